"""The design choices of TVD-DA, measured (docs/tracking.md, sections 1 to 3).

Usage: .venv/bin/python scripts/da_variants.py [--scenarios circle,passage,formation]

Full-team simulations of single integrators (every built-in's own team, gain, step and
start; the passage's unicycles are run as single integrators here, to compare laws, not
robots), with dense J = dc/dp, dc/dt and the guess v at each step; second-half mean e_a of:

- ``lloyd``: kappa (c - p) + v + (I + J) rho (Lloyd's plain feedback beside the one-hop correction);
- ``da``: v + (I + J)(kappa (c - p) + rho) (covswarm.tvd.control.tvd_da's form, v = S's
  affine field);
- ``da+sweep``: one more Neumann term, v + (I + J + J^2)(kappa (c - p) + rho), which needs
  three-hop positions an agent does not have;
- ``exact``: (I - J)^-1 dc/dt + (I + J) kappa (c - p), TVD-C's exact feedforward;
- with a density, ``bump-drift``: v blended with the bump's drift alone, and ``motion``:
  covswarm.tvd.control.motion_field (the drift plus S's stretch and turn, what tvd_da uses).
"""

from __future__ import annotations

import click
import numpy as np

from covswarm.mission.scenario_files import load_scenario
from covswarm.tvd import control, coverage


def guess(variant: str, polygon, velocity, positions, density) -> np.ndarray:
    """The field v at the robots, (n, 2), for one variant."""
    if variant == "motion":
        return control.motion_field(polygon, velocity, positions, density)
    field = control.affine_field(polygon, velocity)(positions)
    if variant == "bump-drift":
        share = density.phi(positions) - density.floor
        weight = (share / density.phi(positions))[:, None]
        return (1 - weight) * field + weight * density.mean_rates[0]
    return field


def run(name: str, variant: str) -> float:
    """Second-half mean e_a of ``variant`` on built-in ``name``, m."""
    scenario = load_scenario(name)
    n, dt, kappa = scenario.agents, scenario.dt, scenario.kappa
    steps = round(scenario.duration / dt)
    p = scenario.initial_positions(n, 0)
    errors = []
    for k in range(steps + 1):
        polygon, velocity = scenario.domain(k * dt)
        density = scenario.density(k * dt)
        c = coverage.mass_centroid(p, polygon, density)[1]
        errors.append(np.linalg.norm(p - c))
        if k == steps:
            break
        J = coverage.centroid_jacobian(p, polygon, density)
        rate = coverage.centroid_rate(p, polygon, velocity, density).ravel()
        feedback = kappa * (c - p).ravel()
        if variant == "exact":
            u = np.linalg.solve(np.eye(2 * n) - J, rate) + feedback + J @ feedback
        else:
            v = guess(variant, polygon, velocity, p, density).ravel()
            rho = rate - v + J @ v
            if variant == "lloyd":
                u = feedback + v + rho + J @ rho
            else:
                r = feedback + rho
                u = v + r + J @ r + (J @ (J @ r) if variant == "da+sweep" else 0.0)
        p = p + dt * u.reshape(-1, 2)
    errors = np.array(errors)
    return float(errors[len(errors) // 2 :].mean())


@click.command()
@click.option("--scenarios", default="circle,passage,formation", show_default=True)
def main(scenarios: str) -> None:
    print("| scenario | variant | steady-state e_a (m) |")
    print("|---|---|---|")
    for name in scenarios.split(","):
        variants = ["lloyd", "da", "da+sweep", "exact"]
        if load_scenario(name).density_path is not None:
            variants += ["bump-drift", "motion"]
        for variant in variants:
            print(f"| {name} | {variant} | {run(name, variant):.5f} |", flush=True)


if __name__ == "__main__":
    main()
