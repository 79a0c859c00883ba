"""The scaffold of a verdict: what the figures of a calibration show, graded ``good`` / ``usable`` / ``not reliable``.

A verdict collects *failures* (each with the advice that would fix it), *weaknesses* and *notes* (what the figures
say beside the camera judged, which grade nothing). A figure is graded against two limits: above the ``usable`` one it
is a failure, above the ``good`` one a weakness. The outcome is ``good`` without failures or weaknesses, ``usable``
with weaknesses only, ``not reliable: <advice>`` with failures; the notes come last among the reasons. The camera's verdict
(:func:`~ccs_kornia.modules.calibration.quality.diagnostics.verdict`) and the rig's
(:func:`~ccs_kornia.modules.rig.rig_diagnostics.rig_verdict`) write their rules on it.
"""

from __future__ import annotations

__all__ = ["Findings"]


class Findings:
    """Failures, their advice and weaknesses, in the order found.

    Example:
        >>> f = Findings()
        >>> f.grade(1.4, 1.0, 2.0, "RMS 1.40 px", "check the corners")
        >>> f.outcome()
        ('usable', ['RMS 1.40 px'])
        >>> f.grade(3.1, 0.5, 2.0, "uncertainty 3.1 px", "add tilted views")
        >>> f.outcome()
        ('not reliable: add tilted views', ['uncertainty 3.1 px', 'RMS 1.40 px'])
        >>> g = Findings()
        >>> g.note("another model fits as well")
        >>> g.outcome()
        ('good', ['another model fits as well'])
    """

    def __init__(self) -> None:
        self.bad: list[str] = []
        self.weak: list[str] = []
        self.advice: list[str] = []
        self.notes: list[str] = []

    def fail(self, reason: str, advice: str) -> None:
        """A failure and what would fix it."""
        self.bad.append(reason)
        self.advice.append(advice)

    def warn(self, reason: str) -> None:
        """A weakness."""
        self.weak.append(reason)

    def note(self, reason: str) -> None:
        """Said among the reasons, graded as nothing."""
        self.notes.append(reason)

    def grade(self, value: float, good: float, usable: float, reason: str, advice: str,
              weakness: str | None = None) -> None:
        """``value`` above ``usable``: a failure (``reason``, ``advice``); above ``good``: a weakness (``weakness``,
        default ``reason``); NaN: nothing."""
        if value > usable:
            self.fail(reason, advice)
        elif value > good:
            self.warn(reason if weakness is None else weakness)

    def outcome(self) -> tuple[str, list[str]]:
        """``("good" | "usable" | "not reliable: <advice>", reasons)``: the failures' advice once each, the
        reasons failures first, the notes last."""
        if self.bad:
            return ("not reliable: " + "; ".join(dict.fromkeys(a for a in self.advice if a)),
                    self.bad + self.weak + self.notes)
        return ("usable" if self.weak else "good"), self.weak + self.notes
