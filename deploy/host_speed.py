"""What one brain-tick costs on this host, measured when ``covswarm run`` starts a packed team.

The launcher packs a big team's brains (deploy.plan.auto_per_process), warns when the team
cannot hold its rate (plan.capacity_note) and keeps the robots' commands alive across the
gaps it expects (plan.command_timeout), all from the CPU one brain-tick costs live. That
cost is the host's: 0.43-0.55 ms on this 2-core VM on 27 Nov 2026 (plan.BRAIN_TICK), 2-3x
that on the same VM on 28-29 Nov, and any other machine differs again. A figure taken from
one day's runs told 28 Nov's launcher to expect 1.6-3.2 Hz from 1000 robots that held
0.44-0.60 (docs/scaling.md).

So the launcher times one pack of CALIBRATION_BRAINS brains over the bench's team
(deploy.bench.time_brain_ticks: sans-IO, every message encoded and decoded as on the wire,
~2 s) and scales it by LIVE_PER_BENCH: a live run's CPU per brain-tick (the run summary's
"CPU per brain-tick (live)", which adds Zenoh's puts and samples) over this figure, both
measured on one host within minutes (docs/scaling.md, "The launcher times the host").
"""

from __future__ import annotations

import time
from dataclasses import dataclass

CALIBRATION_BRAINS = 100  # brains in the pack timed, the whole team (0.2 m apart, 10 Hz)
# periods before timing: fewer than deploy.bench.BRAIN_TICK_WARM (the launcher waits for
# it), the neighbour exchange not quite settled; LIVE_PER_BENCH was measured with it
CALIBRATION_WARM = 25
CALIBRATION_ROUNDS = 6  # periods timed
# A live run's CPU per brain-tick over the calibration pack's, one host, interleaved:
# 29 Nov 2026, docs/scaling.md "The launcher times the host".
LIVE_PER_BENCH = 1.6


@dataclass(frozen=True)
class HostBrainTick:
    """``brain_tick``: s of CPU one brain-tick costs live on this host (LIVE_PER_BENCH x
    ``bench``); ``bench``: s per brain-tick of the calibration pack; ``took``: s of wall
    time the measurement took."""

    brain_tick: float
    bench: float
    took: float

    def describe(self) -> str:
        """One line for the launcher's log."""
        return (
            f"this host: ~{1e3 * self.brain_tick:.3g} ms of CPU a brain-tick (a pack of "
            f"{CALIBRATION_BRAINS} brains timed in {self.took:.1f} s at "
            f"{1e6 * self.bench:.0f} us, x{LIVE_PER_BENCH:g} for Zenoh; --brain-tick sets it)"
        )


def measure_brain_tick(
    brains: int = CALIBRATION_BRAINS,
    warm: int = CALIBRATION_WARM,
    rounds: int = CALIBRATION_ROUNDS,
) -> HostBrainTick:
    """Time one pack of ``brains`` brains, the whole team, ``warm`` periods then ``rounds``
    timed (CPU), and scale it to a live brain-tick (LIVE_PER_BENCH)."""
    from covswarm.deploy.bench import BRAIN_TICK_SPACING, make_layout, time_brain_ticks

    start = time.perf_counter()
    layout = make_layout(brains, "cvt", 0, spacing=BRAIN_TICK_SPACING)
    row = time_brain_ticks(brains, layout, warm=warm, rounds=rounds)
    bench = row["brain_tick_cpu_us"] * 1e-6
    return HostBrainTick(LIVE_PER_BENCH * bench, bench, time.perf_counter() - start)
