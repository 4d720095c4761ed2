"""What ``bench run`` records about the unit under test, the station and the instruments' lab
identity, and the confirmation a run on an instrument past its calibration due date needs
(``docs/units-under-test.md``).

An instrument is overdue when its config ``calibration_due`` date is before today's UTC date (due
*on* that day: a run that day is still in calibration). Overdue instruments of the run are
confirmed before any instrument is opened: by ``--accept-overdue-calibration``, else through the
operator prompt mechanism (a person at the terminal, or an answers file with the key
``calibration_overdue_<instrument>``); a dry-run does not confirm by itself, as the config may
describe real instruments. A run nobody can confirm is refused before it starts
(:func:`check_confirmable`, exit 2); every answer is recorded as an ``operator`` event, source
``calibration`` (:func:`confirm_overdue`), and a "no" aborts the run (exit 1).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from datetime import date
from typing import Iterable, Sequence

from bench.config import LabConfig
from bench.errors import BenchError, InputError, InputErrors, Location
from bench.identity import RunIdentity, check_identity_text, default_station
from bench.procedure import Procedure
from bench.record import RunRecorder, layout
from bench.runner.operator import Operator, answer_verdict

ACCEPT_OPTION = "--accept-overdue-calibration"
"""The ``bench run`` option that confirms every overdue calibration of the run (and the source
recorded with that answer)."""


class CalibrationDeclined(BenchError):
    """The operator did not confirm a run on an instrument past its calibration due date."""


@dataclass(frozen=True)
class OverdueCalibration:
    """An instrument of the run whose calibration was due before ``today`` (UTC dates)."""

    instrument: str
    due: date
    today: date
    location: Location | None
    """Where the config gives ``calibration_due``."""

    @property
    def key(self) -> str:
        """Prompt id of its confirmation (answers-file key)."""
        return f"calibration_overdue_{self.instrument}"

    def describe(self) -> str:
        """``NAME: calibration was due YYYY-MM-DD (N days ago, UTC)``."""
        return f"{self.instrument}: calibration was due {self.due.isoformat()} ({(self.today - self.due).days} days ago, UTC)"

    def question(self) -> str:
        """The confirmation asked of the operator."""
        return f"{self.describe()}; run with it anyway?"


def run_identity(procedure: Procedure, config: LabConfig, *, unit: str | None, part: str | None = None,
                 revision: str | None = None, station: str | None = None) -> RunIdentity:
    """The run's identity from ``bench run --unit/--part/--revision/--station`` (None: not given),
    each checked (:func:`bench.identity.check_identity_text`); the station defaults to the config's
    ``station:``, then to the host name. A procedure with ``requires: {unit: true}`` and no ``unit``
    is refused with an :class:`InputError` located at that key."""
    if unit is None and procedure.unit_required_at is not None:
        raise InputError(f"procedure {procedure.name!r} requires a unit under test: give --unit SERIAL (and --part, --revision)",
                         procedure.unit_required_at, "requires.unit")
    for option, value in (("--unit", unit), ("--part", part), ("--revision", revision), ("--station", station)):
        if value is not None:
            check_identity_text(value, None, option)
    return RunIdentity(unit or "", part or "", revision or "", station or config.station or default_station())


def root_attrs(identity: RunIdentity) -> dict[str, str]:
    """The run file's root identity attributes (:data:`layout.IDENTITY_ATTRS`) of ``identity``."""
    return {layout.ATTR_UNIT_SERIAL: identity.unit_serial, layout.ATTR_UNIT_PART: identity.unit_part,
            layout.ATTR_UNIT_REVISION: identity.unit_revision, layout.ATTR_STATION: identity.station}


def declared_identity(config: LabConfig, names: Iterable[str]) -> dict[str, dict[str, str]]:
    """Instrument name -> the identity its lab config declares (``serial``, ``firmware``,
    ``calibration_due`` as :data:`layout.INSTRUMENT_CONFIG_ATTRS`), only what is declared."""
    out: dict[str, dict[str, str]] = {}
    for name in names:
        inst = config.instruments[name]
        values = {layout.ATTR_CONFIG_SERIAL: inst.serial, layout.ATTR_CONFIG_FIRMWARE: inst.firmware,
                  layout.ATTR_CALIBRATION_DUE: inst.calibration_due.isoformat() if inst.calibration_due else ""}
        out[name] = {k: v for k, v in values.items() if v}
    return out


def overdue_calibrations(config: LabConfig, names: Iterable[str], today: date) -> list[OverdueCalibration]:
    """The instruments ``names`` whose config ``calibration_due`` is before ``today`` (UTC date)."""
    return [OverdueCalibration(n, inst.calibration_due, today, inst.calibration_due_location)
            for n in names if (inst := config.instruments[n]).calibration_due is not None and inst.calibration_due < today]


def check_confirmable(overdue: Sequence[OverdueCalibration], operator: Operator, accept: bool) -> None:
    """Refuse (located :class:`InputErrors`, exit 2) a run with overdue instruments that nobody can
    confirm: no ``--accept-overdue-calibration``, no terminal, no answer in the answers file."""
    if accept:
        return
    unconfirmed = [o for o in overdue if not operator.can_answer(o.key, simulated=False)]
    if unconfirmed:
        raise InputErrors([
            InputError(f"{o.describe()}; confirm on a terminal, with '{o.key}: yes' in --answers FILE, or with {ACCEPT_OPTION}",
                       o.location, "calibration_due")
            for o in unconfirmed
        ])


def confirm_overdue(overdue: Sequence[OverdueCalibration], operator: Operator, accept: bool, recorder: RunRecorder,
                    who: str) -> None:
    """Ask for (or take from ``accept``) the confirmation of every overdue instrument and record
    each answer (event ``operator``, source ``calibration``, at run time 0 s: before the run).
    Raises :class:`CalibrationDeclined` at the first answer that is not a yes (a no, or anything
    else: nothing has moved yet, the operator can start again), and the operator's
    :class:`~bench.runner.operator.NoAnswer` when the terminal's input ends."""
    for o in overdue:
        if accept:
            answer, source = "yes", ACCEPT_OPTION
        else:
            answer, source = operator.ask(o.key, o.question(), simulated=False)
        recorder.event(layout.EVENT_OPERATOR, layout.SOURCE_CALIBRATION, json.dumps({
            "id": o.key, "instrument": o.instrument, "calibration_due": o.due.isoformat(), "date": o.today.isoformat(),
            "answer": answer, "source": source, "operator": who}), t_s=0.0)
        if answer_verdict(answer) != "yes":
            raise CalibrationDeclined(f"{o.instrument}: calibration overdue since {o.due.isoformat()} and the operator "
                                      f"answered {answer!r} ({source}); run not started")
