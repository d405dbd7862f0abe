"""The exit statuses of every ``rig`` command: one meaning each, whatever the command.

A CI job or a script reads only these; a command that cannot tell 1 from 3 has not decided
what went wrong, so each path picks the one that says it.
"""

EXIT_OK = 0  # passed, or done as asked
EXIT_FAIL = 1  # a verdict failed, or the operation asked for did not succeed
EXIT_USAGE = 2  # bad arguments or input files: refused before anything ran
EXIT_ENV = 3  # the surroundings: no bus, link, display or program; a channel busy with others
EXIT_INTERRUPTED = 130  # stopped by a signal (SIGINT, SIGTERM, ...) before a verdict

__all__ = ["EXIT_ENV", "EXIT_FAIL", "EXIT_INTERRUPTED", "EXIT_OK", "EXIT_USAGE"]
