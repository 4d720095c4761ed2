"""What a ``bench`` process imports before it needs it. The suite starts hundreds of them (dry-runs,
reports, the CLI's error paths), and so does a lab's script: importing ``scipy.signal`` alone takes
~1 s on the 2-core machine, more than the rest of a short dry-run (docs/testing.md)."""

from __future__ import annotations

import subprocess
import sys

from tests.conftest import ROOT


def test_building_the_simulated_board_does_not_import_scipy_signal():
    """The sensor models import ``lfilter`` where they filter (a Gauss-Markov term, a lag), not at
    import: a dry-run whose sensor has neither never loads scipy.signal (2.0 s -> 0.8 s a run)."""
    code = ("import sys\n"
            "from bench.clock import VirtualClock\n"
            "from bench.config import load_config\n"
            "from bench.sim.factory import build_devices\n"
            "build_devices(load_config(sys.argv[1]), VirtualClock(), ['acs_board'])\n"
            "print(sorted(m for m in sys.modules if m == 'scipy.signal' or m.startswith('scipy.signal.')))\n")
    r = subprocess.run([sys.executable, "-c", code, str(ROOT / "configs" / "sim.yaml")], cwd=ROOT, capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]", r.stdout
