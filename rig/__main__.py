"""``python -m rig`` is the ``rig`` command. Run by a Python without the rig's packages (the
system's, outside the venv ``./hil install`` makes), it says so instead of a traceback."""

import sys


def _missing(exc: ModuleNotFoundError) -> int:
    print(f"rig: this Python ({sys.executable}) lacks the rig's package {exc.name!r}: it is "
          "not the rig's environment. Run ./hil install once (it makes .venv and builds the "
          "programs), then .venv/bin/rig (or source .venv/bin/activate first).",
          file=sys.stderr)
    return 3


def _run() -> int:
    try:
        from rig.cli import main

        return main()
    except ModuleNotFoundError as exc:
        if exc.name is None or exc.name.partition(".")[0] == "rig":
            raise  # the rig itself is broken: show where
        return _missing(exc)


sys.exit(_run())
