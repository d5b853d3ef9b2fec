"""What the engine raises: a script that cannot run, one refused by validation, a stop the caller asked for."""

from __future__ import annotations


class WorkflowError(Exception):
    """A script that cannot run: unknown step, missing value, bad wiring."""


class ScriptError(WorkflowError):
    """A script refused by validation; ``problems`` lists each mistake with its line and fix."""

    def __init__(self, script: str, problems: list[str]) -> None:
        self.script = script
        self.problems = problems
        super().__init__(f"{script}: {len(problems)} problem(s), nothing was run:\n  " + "\n  ".join(problems))


class Cancelled(Exception):
    """The caller asked the workflow to stop; raised at the next step or item boundary."""
