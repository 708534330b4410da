"""The paper's experiment: coupled visuomotor tracking on a computer screen (paper section 4).

Subjects move a mouse that *is* the lower end of a stick (x_M, or q_M1 and
q_M2); the server computes the upper ends with the reduced model (eq.
(3) single, eq. (5) coupled) at 50 Hz and a web page draws the
lines.  Recordings are appended to disk as the trial runs and are analysed
with the same metrics as the models (:mod:`validation.checks.metrics`).

Modules, one job each:

* :mod:`.screen`    -- screen geometry: model displacement <-> pixel.
* :mod:`.task`      -- the task model stepped between 20 ms frames (engines).
* :mod:`.trial`     -- one trial frame by frame: end rules, samples.
* :mod:`.recording` -- append-only recording, finalisation, loader.
* :mod:`.finalize`  -- recordings finalised off the server's event loop.
* :mod:`.bot`       -- the pseudo-neural controller as a subject.
* :mod:`.protocol`  -- validation of messages from the page.
* :mod:`.session`   -- seats, countdown, the real-time 50 Hz loop.
* :mod:`.server`    -- aiohttp web server (page + WebSocket).
* :mod:`.headless`  -- bot-vs-bot trials at full speed, without a browser.
* :mod:`.analysis`  -- tau_hat and RMS per trial and subject; Tables STCC and RMS.
* :mod:`.report`    -- Figs. move_s, move_c, stcc_s, stcc_c, rmstau; report.md/html.
* :mod:`.cli`       -- ``cip-validate experiment ...``.
"""
