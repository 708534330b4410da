"""The command line, at the edge: ``cip-validate`` and its subcommands.

* :mod:`~validation.cli.main`: the entry point (``cip-validate``), lazy imports only;
* :mod:`~validation.cli.args`: the parser, option types and their domains;
* :mod:`~validation.cli.commands`: one module per family of subcommands;
* :mod:`~validation.cli.ci_options`, :mod:`~validation.cli.engine_options`: option groups
  shared by several commands;
* :mod:`~validation.cli.exitcodes`, :mod:`~validation.cli.junit`,
  :mod:`~validation.cli.checklog`: exit codes, JUnit XML and the printed check table.
"""
