"""The documentation: README.md, docs/*.md and the MkDocs site they build.

Shell blocks.  Every fenced ``bash``, ``sh``, ``shell`` or ``console`` block of
README.md and docs/**/*.md is run here unless the line just before its opening fence
is a marker:

    <!-- not-run: REASON -->   not run, for the stated REASON (slow, needs a display,
                               a GPU, a compiler, a server); the reason is required
    <!-- exit: N -->           run, and it must exit with status N instead of 0

The blocks of one page run in order, each as a bash script (``set -e -o pipefail``)
in one temporary directory where ``examples/``, ``models/`` and ``benchmarks/`` link
to the repository's (so the blocks read as a reader runs them and write nothing into
the checkout), with this interpreter's ``bin/`` first on PATH, under a timeout of
:data:`BLOCK_TIMEOUT` s.  A ``console`` block runs its ``$ `` lines only.  Keep the
runnable blocks cheap (seconds); mark anything slow not-run with the reason (a full
``cip-validate run`` is the quickstart, run by CI's own steps).

Besides: the README has at most :data:`README_MAX_LINES` lines and its links to local
files resolve; every repository path and module name the pages cite in inline code
exists; the worked frame of the chunk protocol (docs/chunk-protocol.md) encodes the
values it names, and MuJoCo's step reproduces its response; the README's in-process
engine passes the engine contract; and, where MkDocs, Material and mkdocstrings are
installed (``pip install -e ".[docs]"``), ``mkdocs build --strict`` succeeds.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import re
import struct
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
PAGES = [README, *sorted((REPO / "docs").rglob("*.md"))]
README_MAX_LINES = 250
#: seconds a runnable block may take (cheap blocks take seconds; CI's machine is shared)
BLOCK_TIMEOUT = 240
SHELLS = ("bash", "sh", "shell", "console")
#: repository folders linked into the blocks' working directory
LINKED = ("examples", "models", "benchmarks")
#: build products the pages may name that a fresh checkout does not have
BUILD_PRODUCTS = {"examples/c_engine/cip_engine"}

_FENCE = re.compile(r"^(\s*)(`{3,}|~{3,})\s*([^\s`]*)")
_MARKER = re.compile(r"^\s*<!--\s*(not-run|exit)\s*:?\s*(.*?)\s*-->\s*$")


@dataclass
class Block:
    page: Path
    line: int  # 1-based line of the opening fence
    lang: str
    text: str
    marker: tuple[str, str] | None  # ("not-run", reason) or ("exit", "N")

    @property
    def where(self) -> str:
        return f"{self.page.relative_to(REPO)}:{self.line}"


def fenced_blocks(page: Path) -> list[Block]:
    """Every fenced block of ``page`` with the marker on the line before it, if any."""
    lines = page.read_text().splitlines()
    blocks, i = [], 0
    while i < len(lines):
        m = _FENCE.match(lines[i])
        if m is None:
            i += 1
            continue
        indent, fence, lang = m.group(1), m.group(2), m.group(3).lower()
        close = re.compile(rf"^\s*{re.escape(fence[0])}{{{len(fence)},}}\s*$")
        j = i + 1
        while j < len(lines) and not close.match(lines[j]):
            j += 1
        body = [x[len(indent) :] if x.startswith(indent) else x.lstrip() for x in lines[i + 1 : j]]
        prev = _MARKER.match(lines[i - 1]) if i > 0 else None
        marker = (prev.group(1), prev.group(2)) if prev else None
        blocks.append(Block(page, i + 1, lang, "\n".join(body) + "\n", marker))
        i = j + 1
    return blocks


def shell_blocks(page: Path) -> list[Block]:
    return [b for b in fenced_blocks(page) if b.lang in SHELLS]


def _script(block: Block) -> str:
    if block.lang == "console":
        return "\n".join(x[2:] for x in block.text.splitlines() if x.startswith("$ ")) + "\n"
    return block.text


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PATH"] = str(Path(sys.executable).parent) + os.pathsep + env.get("PATH", "")
    env.update(MPLBACKEND="Agg", TQDM_DISABLE="1", PYTHONUNBUFFERED="1")
    return env


def _page_id(page: Path) -> str:
    return str(page.relative_to(REPO))


# ------------------------------------------------------------------ shell blocks
def test_markers_are_well_formed():
    """Each marker stands right before a shell block; not-run states its reason, exit
    a status; no marker is misspelt into a comment that marks nothing."""
    problems = []
    for page in PAGES:
        lines = page.read_text().splitlines()
        for k, line in enumerate(lines):
            if not line.lstrip().startswith("<!--") or not re.search(r"not-run|exit", line):
                continue
            m = _MARKER.match(line)
            nxt = _FENCE.match(lines[k + 1]) if k + 1 < len(lines) else None
            where = f"{_page_id(page)}:{k + 1}"
            if m is None:
                problems.append(f"{where}: malformed marker {line.strip()!r}")
            elif nxt is None or nxt.group(3).lower() not in SHELLS:
                problems.append(f"{where}: marker not followed by a shell block")
            elif m.group(1) == "not-run" and not m.group(2):
                problems.append(f"{where}: not-run without a reason")
            elif m.group(1) == "exit" and not m.group(2).isdigit():
                problems.append(f"{where}: exit without a status")
    assert not problems, "\n".join(problems)


PAGES_WITH_RUNNABLE = [p for p in PAGES if any(b.marker is None or b.marker[0] == "exit"
                                               for b in shell_blocks(p))]  # fmt: skip


@pytest.mark.parametrize("page", PAGES_WITH_RUNNABLE, ids=_page_id)
def test_shell_blocks_run(page, tmp_path):
    """The page's runnable shell blocks, in order, in one directory: each exits as marked."""
    for name in LINKED:
        (tmp_path / name).symlink_to(REPO / name, target_is_directory=True)
    env = _env()
    for block in shell_blocks(page):
        if block.marker is not None and block.marker[0] == "not-run":
            continue
        want = int(block.marker[1]) if block.marker else 0
        try:
            proc = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", _script(block)],
                                  cwd=tmp_path, env=env, capture_output=True, text=True,
                                  timeout=BLOCK_TIMEOUT)  # fmt: skip
        except subprocess.TimeoutExpired:
            pytest.fail(f"{block.where}: ran past {BLOCK_TIMEOUT} s; mark it not-run with the "
                        "reason, or make it cheaper:\n" + block.text)  # fmt: skip
        assert proc.returncode == want, (
            f"{block.where}: exit {proc.returncode}, expected {want}\n{block.text}"
            f"--- stdout (end)\n{proc.stdout[-3000:]}\n--- stderr (end)\n{proc.stderr[-3000:]}"
        )


def _not_run_commands() -> list[tuple[str, list[str]]]:
    """(where, words) of every ``cip-validate`` and ``python benchmarks/NAME.py`` command
    in the pages' not-run blocks, continuation lines joined and comments dropped; a
    synopsis (``[--opt X]``, ``a|b``, ``CMD ARGS``) is not a command."""
    import shlex

    out = []
    for page in PAGES:
        for block in shell_blocks(page):
            if block.marker is None or block.marker[0] != "not-run":
                continue
            for k, line in enumerate(_script(block).replace("\\\n", " ").splitlines()):
                words = shlex.split(line, comments=True)
                if not words or re.search(r"[\[|]|CMD ARGS", line.split("#")[0]):
                    continue
                script = words[0] == "python" and words[1:2] and words[1].startswith("benchmarks/")
                if words[0] == "cip-validate" or script:
                    out.append((f"{block.where} +{k}", words))
    return out


class _Parsed(Exception):
    """Raised by the patched ``parse_args`` once a script's arguments parsed."""


def test_not_run_commands_parse(monkeypatch):
    """Every command the pages show but do not run (slow, needs a GPU...) at least parses:
    ``cip-validate`` lines by the CLI's own parser, ``python benchmarks/NAME.py`` lines by
    the script's (its ``main`` stopped right after ``parse_args``).  An option renamed or
    removed would otherwise leave a documented command that fails at once.  An input file
    that is absent is no failure: the block's earlier commands write it."""
    import argparse
    import contextlib
    import importlib.util
    import io

    from validation.cli.main import build_parser

    commands = _not_run_commands()
    assert len(commands) >= 20, commands  # the pages show a few dozen
    parser = argparse.ArgumentParser
    parse, parse_known = parser.parse_args, parser.parse_known_args
    inside = []  # parse_args calls parse_known_args: stop only at the outer call

    def parse_then_stop(self, args=None, namespace=None):
        inside.append(True)
        try:
            parse(self, args, namespace)
        finally:
            inside.pop()
        raise _Parsed

    def parse_known_then_stop(self, args=None, namespace=None):
        out = parse_known(self, args, namespace)
        if inside:
            return out
        raise _Parsed  # the script passes what it does not know on (bench_tests: to pytest)

    monkeypatch.syspath_prepend(str(REPO / "benchmarks"))
    failures = []
    for where, words in commands:
        err = io.StringIO()
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                if words[0] == "cip-validate":
                    build_parser(full=True).parse_args(words[1:])
                    continue
                script = REPO / words[1]
                spec = importlib.util.spec_from_file_location(f"_doc_{script.stem}", script)
                module = importlib.util.module_from_spec(spec)
                monkeypatch.setitem(sys.modules, spec.name, module)  # for its dataclasses
                spec.loader.exec_module(module)
                if "argparse" not in script.read_text():  # a script without options
                    if words[2:]:
                        failures.append(f"{where}: {' '.join(words)}: takes no arguments")
                    continue
                monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_then_stop)
                monkeypatch.setattr(
                    argparse.ArgumentParser, "parse_known_args", parse_known_then_stop
                )
                monkeypatch.setattr(sys, "argv", [str(script), *words[2:]])
                try:
                    module.main()
                finally:
                    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse)
                    monkeypatch.setattr(argparse.ArgumentParser, "parse_known_args", parse_known)
                failures.append(f"{where}: {' '.join(words)}: main() returned before parsing")
        except _Parsed:
            pass
        except SystemExit:
            if "no such file" not in err.getvalue():  # an input an earlier line writes
                failures.append(f"{where}: {' '.join(words)}: {err.getvalue().strip()}")
    assert not failures, "\n".join(failures)


# ------------------------------------------------------------------ the README
def test_readme_is_a_front_door():
    n = len(README.read_text().splitlines())
    assert n <= README_MAX_LINES, f"README.md has {n} lines; at most {README_MAX_LINES}"


def test_readme_keeps_the_quickstart_commands():
    """CI runs the README's test command as written (.ci/run); the quickstart keeps both."""
    text = README.read_text()
    assert 'pip install -e ".[test]" && pytest' in text
    assert "pip install -e . && cip-validate run" in text
    assert 'pip install -e ".[test]" && pytest' in (REPO / ".ci" / "run").read_text()


def test_readme_links_resolve():
    missing = []
    for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", README.read_text()):
        if "://" not in target and not (REPO / target).exists():
            missing.append(target)
    assert not missing, f"README.md links to files that do not exist: {missing}"


# ------------------------------------------------------------------ what the pages cite
_CODE = re.compile(r"(?<!`)`([^`\s]+)`(?!`)")
_PATH_ROOTS = ("cip/", "cipcore/", "reduced/", "validation/", "models/", "examples/",
               "benchmarks/", "tests/", "docs/", ".ci/")  # fmt: skip
_DOTTED = re.compile(r"^(?:cipcore|cip|reduced|validation)(?:\.[A-Za-z_]\w*)+$")


def _prose(page: Path) -> str:
    """The page without its fenced blocks (code there is an example, not a citation)."""
    lines = page.read_text().splitlines()
    spans = {(b.line, b.line + b.text.count("\n")) for b in fenced_blocks(page)}
    skip = {k for a, z in spans for k in range(a - 1, z + 1)}
    return "\n".join(x for k, x in enumerate(lines) if k not in skip)


def _cited(kind: str) -> list[tuple[str, str]]:
    out = []
    for page in PAGES:
        for token in _CODE.findall(_prose(page)):
            token = token.rstrip(".,;:")
            if kind == "path" and token.startswith(_PATH_ROOTS):
                if not any(c in token for c in "<>*{}$"):
                    out.append((_page_id(page), token))
            elif kind == "name" and _DOTTED.match(token):
                out.append((_page_id(page), token))
    return out


def test_cited_paths_exist():
    missing = [f"{page}: {path}" for page, path in _cited("path")
               if path not in BUILD_PRODUCTS and not (REPO / path).exists()]  # fmt: skip
    assert not missing, "paths cited that do not exist:\n" + "\n".join(missing)


def _resolves(name: str) -> bool:
    """``name`` is a module, or a module's attribute (chain); an attribute of a module
    that cannot be imported here (an optional engine's package) is given the benefit."""
    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        module = ".".join(parts[:k])
        try:
            found = importlib.util.find_spec(module) is not None
        except (ImportError, ValueError):
            found = False
        if not found:
            continue
        if k == len(parts):
            return True
        try:
            obj = importlib.import_module(module)
        except ImportError:
            return True
        for attr in parts[k:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return False


def test_cited_module_names_exist():
    missing = sorted({f"{page}: {name}" for page, name in _cited("name") if not _resolves(name)})
    assert not missing, "module names cited that do not exist:\n" + "\n".join(missing)


# ------------------------------------------------------------------ the chunk protocol
_DUMP = re.compile(r"^([0-9a-f]{4}):\s+((?:[0-9a-f]{2} ){7}[0-9a-f]{2})\s+(.*)$")


def _frames() -> list[list[tuple[int, bytes, str]]]:
    """The hex dumps of docs/chunk-protocol.md: per dump, (offset, 8 bytes, field)."""
    dumps = []
    for block in fenced_blocks(REPO / "docs" / "chunk-protocol.md"):
        rows = [_DUMP.match(x) for x in block.text.splitlines()]
        rows = [(int(m.group(1), 16), bytes.fromhex(m.group(2)), m.group(3)) for m in rows if m]
        if rows:
            dumps.append(rows)
    return dumps


def test_protocol_frame_encodes_the_values_it_names():
    dumps = _frames()
    assert len(dumps) == 2, "expected the request and the response dump"
    for rows in dumps:
        assert [off for off, _, _ in rows] == list(range(0, 8 * len(rows), 8))
        for off, raw, field in rows:
            value = re.search(r"=\s*(-?[0-9][0-9.eE+-]*)", field).group(1)
            want = struct.pack("<q", int(value)) if "(int64)" in field else struct.pack(
                "<d", float(value))  # fmt: skip
            assert raw == want, f"offset {off:04x} ({field}): {raw.hex(' ')} != {want.hex(' ')}"
    request, response = dumps
    assert len(request) * 8 == 8 + 1 * 5 * 8 + 1 * 1 * 3 * 8  # 8 + R S 8 + R n U 8 = 72
    assert len(response) * 8 == 8 + 1 * 1 * 5 * 8  # 8 + R n S 8 = 48


def test_protocol_frame_response_is_the_step_of_the_shipped_single_model():
    """MuJoCo's Euler step of models/cip_single.xml from the request's state and control
    gives the response's state (the C engine matches it to round-off on the single model)."""
    import mujoco
    import numpy as np

    from cip.mjcf_params import load_model_file, shipped_model_path

    request, response = _frames()
    state = np.frombuffer(b"".join(raw for _, raw, _ in request[1:6]), "<f8")
    ctrl = np.frombuffer(b"".join(raw for _, raw, _ in request[6:]), "<f8")
    want = np.frombuffer(b"".join(raw for _, raw, _ in response[1:]), "<f8")
    m = load_model_file(shipped_model_path("single"))
    d = mujoco.MjData(m)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    mujoco.mj_setState(m, d, state, spec)
    d.ctrl[:] = ctrl
    mujoco.mj_step(m, d)
    got = np.empty(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, d, got, spec)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=0)


# ------------------------------------------------------------------ the README's engine
def test_readme_in_process_engine_passes_the_contract(tmp_path):
    from validation.checks.contract import run_contract

    code = [b.text for b in fenced_blocks(README) if b.lang == "python"
            and "ENGINE = RigidBodyEngine(" in b.text]  # fmt: skip
    assert len(code) == 1, "the README's in-process engine example"
    path = tmp_path / "readme_engine.py"
    path.write_text(code[0])
    spec = importlib.util.spec_from_file_location("readme_engine", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    results = run_contract(module.ENGINE)
    failed = [r for r in results if r["status"] not in ("pass", "skip")]
    assert results and not failed, failed


# ------------------------------------------------------------------ the site
_DOCS_PACKAGES = ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers.python")


def test_site_builds_without_warnings(tmp_path):
    absent = []
    for name in _DOCS_PACKAGES:
        try:
            if importlib.util.find_spec(name) is None:
                absent.append(name)
        except ImportError:
            absent.append(name)
    if absent:
        pytest.skip(f"MkDocs not installed ({', '.join(absent)}): pip install -e '.[docs]'")
    env = dict(_env(), NO_MKDOCS_2_WARNING="1")
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir",
                           str(tmp_path / "site"), "--config-file", str(REPO / "mkdocs.yml")],
                          cwd=REPO, env=env, capture_output=True, text=True,
                          timeout=300)  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    assert (tmp_path / "site" / "index.html").exists()


# ------------------------------------------------------------------ generated engine tables
def _engine_run_hook():
    spec = importlib.util.spec_from_file_location("engine_run", REPO / "docs/hooks/engine_run.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_engine_tables_are_rendered_from_a_stored_run():
    """Each ``engines-run`` marker names a stored results.json of ``cip-validate engines``;
    the hook renders the command's own report from it (every engine of the run a row, its
    verdict and the run's command in the text), and no page holds a hand-copied table of
    the same header instead."""
    import json

    hook = _engine_run_hook()
    pages = sorted((REPO / "docs").glob("*.md"))
    marked = [p for p in pages if hook._MARKER.search(p.read_text())]
    assert marked, "no page renders the engine tables from a run"
    for page in marked:
        for m in hook._MARKER.finditer(page.read_text()):
            results = json.loads((REPO / "docs" / m.group(1)).read_text())
            text = hook.render(results)
            assert results["run"]["command"].startswith("cip-validate engines")
            assert f"`{results['run']['command']}`" in text
            for row in results["engines"]:
                assert f"| {row['engine']} | {row['status']} |" in text
    header = "| engine | verdict | family | precision | integrator | rod | tier"
    for page in pages:
        assert header not in page.read_text(), f"{page.name}: a hand-copied engine table"
