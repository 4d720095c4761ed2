"""One run with a die-temperature channel that rises after power-on (issue 32): what it tells about a
warm-up, a random walk and the S5 phone's own wander (docs/diagnose.md, Known limits, "A die
temperature channel in one run").

The construction is the real-noise sweep's (tests/test_real_data_diagnose.py ``in_background``: a
generated tvac session at 1 Hz whose white noise is an hour of the S5 phone at rest; its unit, mount
and session from the seed), with three changes: the sensor's own temperature cubic set to zero, the
gyro's other inputs kept, and the ``temp_c`` column replaced by a die that warms after power-on,
T0 + ΔT·(1 − exp(−t/τ_T)), ΔT = 4 °C above its mount (NPSAT1 IV.B.3, the simulator's
``self_heating_c``), read at the simulator's 0.01 °C (docs/simulation.md, sensor board table). So the
temperature moves only with time since power-on, as on a bench at room temperature.

What holds (measured 2026-11-28 on this construction; the figures in the docs):

* one run cannot tell a warm-up that follows that temperature from one that follows time since
  power-on: over a monotone rise any smooth function of time is a function of temperature, and the
  baseline's temperature cubic takes either (no warm-up name; most of the warm-up in the cubic);
  without the channel the same warm-up is named ``warmup_transient``;
* the channel gives no temperature name (or any deterministic name) to a random walk or to the
  phone's own wander, although the cubic takes part of them;
* the output says so: every axis whose cubic holds ≥ 0.03 deg/s is in ``temperature_in_time``
  with its summary line (``confounded.py``).

Outside truth: the S5 noise is real; the temperature channel, its coupling to the bias and the
warm-up shape are our construction. ``BENCH_SLOW=1``: 6 runs of 1 h, about 50 s.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.polynomial import polynomial as P

from bench.analysis.diagnose import diagnose
from bench.sessions import TEMP_RESOLUTION_C, BaselineSensor, make_session
from tests.diagnose_shapes import background, scale_against
from tests.test_real_data_diagnose import _seed, deterministic, hidden_effect

pytestmark = pytest.mark.slow

SELF_HEATING_C = 4.0
"""Die above its mount (°C): NPSAT1 IV.B.3 "as much as 4 °C" (bench/model/chamber.py ``self_heating_c``)."""
T0_C = 20.0
TEMP_NAMES = {"thermal_lag", "warmup_transient", "hysteresis", "scale_factor_tempco"}
WARMUP_SEED = _seed("real", "s5", "warmup_transient", 2)
"""The sweep's S5 warm-up (+0.159 deg/s, τ 292 s on y) that one run in the tvac session calls a walk."""


def self_heating_run(seed: int, warm: str | None, tau_t_s: float | None, walk_k: float = 0.0, walk_seed: int = 0):
    """(dataset, the warm-up entry the seed draws): ``warm`` None (nothing injected), ``"time"``
    (A·exp(−t/τ)) or ``"temp"`` (k·(T − T_end), k = −A/ΔT: the same curve when τ_T = τ); a random
    walk K ``walk_k`` deg/s/√s on the warm-up's axis; ``tau_t_s`` None: temperature flat at T0."""
    rng = np.random.default_rng([seed, 32])
    mount = str(rng.choice(["z", "x", "-y"]))
    base = BaselineSensor.random(rng, 1.0)
    base.noise_dps = 0.0
    base.poly_dps[:] = 0.0
    sess_seed = int(rng.integers(2**31))
    probe = make_session(3600.0, 1.0, [], seed=sess_seed, mount=mount, base=base)
    e = hidden_effect("warmup_transient", rng, mount, scale_against("s5"), probe, base)
    k, amp, tau = "xyz".index(e["axis"]), e["params"]["amplitude_dps"], e["params"]["tau_s"]
    t = np.arange(3600, dtype=float)
    die = T0_C + (SELF_HEATING_C * (1.0 - np.exp(-t / tau_t_s)) if tau_t_s else 0.0 * t)
    add = background("s5", 3600, seed)
    if warm == "time":
        add[:, k] += amp * np.exp(-t / tau)
    elif warm == "temp":
        add[:, k] += -amp / SELF_HEATING_C * (die - die[-1])
    if walk_k:
        add[:, k] += np.cumsum(np.random.default_rng([walk_seed, 99]).normal(0.0, walk_k, t.size))
    ds = make_session(3600.0, 1.0, [], seed=sess_seed, mount=mount, base=base, extra=lambda inp: add.copy()).dataset
    ds.columns["temp_c"] = np.round(die / TEMP_RESOLUTION_C) * TEMP_RESOLUTION_C
    return ds, e


def in_the_cubic(result, ds, axis: str) -> float:
    """The bias (deg/s) the fitted baseline's temperature cubic puts between the first and the last row."""
    c = result.fitted_baseline["in_run_poly"]["xyz".index(axis)]
    temp = ds["temp_c"]
    return float(P.polyval(temp[0], c) - P.polyval(temp[-1], c))


def test_one_run_cannot_tell_a_warm_up_that_follows_the_die_temperature_from_one_that_does_not(real_log):
    """A warm-up following the self-heating (τ_T = τ) and one following time since power-on beside a
    self-heating of τ_T = 1000 s end alike: no warm-up name, most of the warm-up in the temperature
    cubic (measured 0.128 and 0.115 of 0.159 deg/s). Without the channel (temperature flat) the
    same warm-up is named: the channel is what takes it."""
    real_log("samsung_galaxy_s5.nc")
    for warm, tau_t in (("temp", 291.8), ("time", 1000.0)):
        ds, e = self_heating_run(WARMUP_SEED, warm, tau_t)
        a, amp = e["axis"], e["params"]["amplitude_dps"]
        r = diagnose(ds)
        assert ("warmup_transient", a) not in deterministic(r) and not TEMP_NAMES & {n for n, _ in deterministic(r)}, \
            (warm, [(f.effect, f.axis, f.params) for f in r.findings])
        assert in_the_cubic(r, ds, a) > 0.5 * amp, (warm, in_the_cubic(r, ds, a), amp)
        said_where_it_holds(r, ds)
        assert a in {e["axis"] for e in r.temperature_in_time}, (warm, r.temperature_in_time)
    ds, e = self_heating_run(WARMUP_SEED, "time", None)
    r = diagnose(ds)
    assert ("warmup_transient", e["axis"]) in deterministic(r), [(f.effect, f.axis, f.params) for f in r.findings]
    assert r.temperature_in_time == []  # no temperature moved: no cubic to say anything of


def said_where_it_holds(result, ds, at_least_dps: float = 0.03) -> None:
    """Every axis whose temperature cubic holds at least ``at_least_dps`` between the first and the
    last row is said to be one run's drift in time as much as a temperature coefficient, with the
    die's 20 -> 24 degC (``confounded.py``), and the sentence is in the summary."""
    said = {e["axis"]: e for e in result.temperature_in_time}
    for a in result.axes:
        if abs(in_the_cubic(result, ds, a)) >= at_least_dps:
            assert a in said, (a, in_the_cubic(result, ds, a), said)
    for e in said.values():
        assert e["monotone"] and e["since_power_on"] and round(e["temp_last_c"]) == T0_C + SELF_HEATING_C, e
        assert any(ln.startswith(f"{e['axis']}: the temperature coefficient holds") for ln in result.summary_lines())


@pytest.mark.parametrize("kind,k,walk_k", [("warmup_transient", 2, 1e-3), ("hours", 0, 0.0), ("bump", 1, 0.0)],
                         ids=["walk", "s5-hour-0", "s5-bump-hour-1"])
def test_a_self_heating_channel_names_nothing_in_a_walk_or_the_phones_wander(real_log, kind, k, walk_k):
    """A random walk (K 1e-3 deg/s/√s on the warm-up's axis, no warm-up) and the S5 hours with nothing
    injected (hour 0 of those the sweep drew; the hour of the bump seed 1 whose wander the tvac
    session names a warm-up), beside the self-heating channel (τ_T 292 s): no deterministic name.
    The cubic takes part of them (measured −0.086, +0.067 and −0.134 deg/s on one axis): the
    limit in the docs, not a name."""
    real_log("samsung_galaxy_s5.nc")
    ds, _ = self_heating_run(_seed("real", "s5", kind, k), None, 291.8, walk_k=walk_k)
    r = diagnose(ds)
    assert deterministic(r) == [], [(f.effect, f.axis, f.params) for f in r.findings]
    said_where_it_holds(r, ds)
