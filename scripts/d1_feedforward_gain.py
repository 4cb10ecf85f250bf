"""Why TVD-D1's feedforward helps by about a quarter on the circle (docs/tracking.md).

Usage: .venv/bin/python scripts/d1_feedforward_gain.py [--agents 100] [--every 2.5]

Runs the ``circle`` scenario with TVD-D1 with and without dc/dt (covswarm sim's simulator,
same seed), then, every ``--every`` seconds of the second half, predicts each run's
quasi-static error from the linearised closed loops (docs/tracking.md, "Why TVD-D1 loses
the feedforward"):

    with dc/dt:    e = -(kappa (I - J^2))^-1 J^2 dc/dt = -(1 / kappa) (I + J)^-1 J^2 v
    without:       e = -(kappa (I - J^2))^-1 dc/dt     = -(1 / kappa) (I + J)^-1 v

(the right-hand forms use dc/dt = (I - J) v, exact at a CVT of a translating domain;
(I + J) is well conditioned where I - J is not). J = dc/dp and v = the domain's velocity
field (covswarm.tvd.control.affine_field) at that run's configuration. Prints the simulated
and predicted |e| and their ratios, then the predicted ratio at a Lloyd-converged CVT of the
square for several team sizes (what decides the feedforward's share: the boundary robots).
"""

from __future__ import annotations

import click
import numpy as np

from covswarm.deploy.simulate import simulate
from covswarm.mission.scenario_files import load_scenario
from covswarm.tvd import control, coverage


def predicted(positions: np.ndarray, polygon: np.ndarray, velocity: np.ndarray, kappa: float):
    """|e| predicted with and without dc/dt at one configuration (module notes), m."""
    n = len(positions)
    jacobian = coverage.centroid_jacobian(positions, polygon)
    field = control.affine_field(polygon, velocity)(positions).ravel()
    plus = np.eye(2 * n) + jacobian
    with_ff = np.linalg.solve(plus, jacobian @ (jacobian @ field)) / kappa
    without = np.linalg.solve(plus, field) / kappa
    return float(np.linalg.norm(with_ff)), float(np.linalg.norm(without))


def cvt_ratio(n: int, seed: int = 0) -> float:
    """Predicted with/without ratio at a CVT of the 2 m square translating (any speed)."""
    square = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    points = np.random.default_rng(seed).uniform(-1, 1, size=(n, 2))
    for _ in range(500):
        points = coverage.mass_centroid(points, square)[1]
    with_ff, without = predicted(points, square, np.tile([0.1, 0.05], (4, 1)), 1.0)
    return with_ff / without


@click.command()
@click.option("--agents", type=int, default=100, show_default=True)
@click.option("--every", type=float, default=2.5, show_default=True, help="s between samples")
def main(agents: int, every: float) -> None:
    scenario = load_scenario("circle")
    runs = {ff: simulate(scenario, agents=agents, law="d1", feedforward=ff) for ff in (True, False)}
    t = runs[True].t
    stride = max(1, round(every / (t[1] - t[0])))
    rows = []
    for k in range(len(t) // 2, len(t), stride):
        polygon, velocity = scenario.domain(t[k])
        row = [t[k]]
        for ff in (True, False):
            positions = runs[ff].trajectories[k]
            guess = predicted(positions, polygon, velocity, scenario.kappa)[0 if ff else 1]
            row += [runs[ff].error[k], guess]
        rows.append(row)
    table = np.array(rows)
    print("| t (s) | e_a with dc/dt | predicted | e_a without | predicted |")
    print("|---|---|---|---|---|")
    for row in table:
        print("| " + " | ".join(f"{x:.4f}" if i else f"{x:.1f}" for i, x in enumerate(row)) + " |")
    mean = table[:, 1:].mean(axis=0)
    print(
        f"\nmeans: simulated with/without {mean[0]:.4f} / {mean[2]:.4f} m = {mean[0] / mean[2]:.3f}"
        f" (improvement {1 - mean[0] / mean[2]:.1%}); predicted {mean[1]:.4f} / {mean[3]:.4f} m"
        f" = {mean[1] / mean[3]:.3f} (improvement {1 - mean[1] / mean[3]:.1%})"
    )
    print("\npredicted improvement at a CVT of the translating square, by team size:")
    for n in (10, 25, 50, 100, 200):
        print(f"  N = {n:3d}: {1 - cvt_ratio(n):.1%}")


if __name__ == "__main__":
    main()
