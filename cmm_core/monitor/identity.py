"""Which machine a stored calibration is of, and which software made it.

A check or a history compares numbers of one machine only: a model file names its machine
(``provenance.machine``, from the setup's ``machine.id``), and a check of another
machine's data, or a history mixing machines, is refused in one line. The layout and the
strokes are compared as well (:mod:`.check`, :mod:`.history`): two machines of one type
share those, their names do not. A model made by another version of the software is
compared all the same, with a note that says so (its numbers were computed by that code).
"""

from __future__ import annotations

from collections.abc import Iterable

from .. import __version__
from ..export import Model
from ..io import DataError

__all__ = ["machine_of", "refuse_mixed_machines", "refuse_other_machine", "version_notes"]


def machine_of(model: Model) -> str | None:
    """The machine a model file names (None: it names none, or predates provenance)."""
    return model.provenance.machine if model.provenance is not None else None


def refuse_other_machine(model: Model, machine: str | None, name: str) -> None:
    """Refuse data of ``machine`` (the new setup's ``machine.id``) against a model of
    another named machine; nothing is refused when either names none."""
    stored = machine_of(model)
    if stored is not None and machine is not None and stored != machine:
        raise DataError(f"the data are of the machine {machine!r}, the stored calibration "
                        f"{model.name} of {stored!r}: a check compares one machine with its "
                        "own calibration.", file=name, column="machine.id",
                        hint="check against this machine's own model file, or correct "
                             "machine.id in the setup.")


def refuse_mixed_machines(models: Iterable[Model]) -> None:
    """Refuse calibrations of different named machines in one history."""
    named = [(m, machine_of(m)) for m in models]
    named = [(m, k) for m, k in named if k is not None]
    for m, k in named[1:]:
        if k != named[0][1]:
            raise DataError(f"the model is of the machine {k!r}, {named[0][0].name} of "
                            f"{named[0][1]!r}: different machines are not compared.",
                            file=m.name, column="provenance.machine",
                            hint="give the calibrations of one machine.")


def version_notes(models: Iterable[Model]) -> list[str]:
    """One note per model made by another version of this software (or by a version
    before model files named it)."""
    notes = []
    for m in models:
        p = m.provenance
        if p is None:
            notes.append(f"{m.name} was made by a version before 0.8.0 (it names none); "
                         f"compared with {__version__}.")
        elif p.version != __version__:
            notes.append(f"{m.name} was made by {p.code}; compared with {__version__}.")
    return notes
