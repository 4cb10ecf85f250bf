"""Time covswarm's step with a time-varying density beside bbao200905/tvd_coverage's, in one
process, on the same layouts of the peer's arena with its two moving bumps.

The protocol, what is timed and the measured result: docs/density-peer.md. The peer is not
part of covswarm: point --peer at the ``pycoverage_robotarium`` folder of a checkout of it,
with its Voronoi dependency installed (``pip install pyvoro-mmalahe==1.3.4``, or
``pip install --target DIR`` and DIR on PYTHONPATH).

    python scripts/density_peer.py --peer ~/tvd_coverage/pycoverage_robotarium --out runs/peer
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from covswarm.tvd.control import local_step, tvd_c
from covswarm.tvd.coverage import mass_centroid, neighbors
from covswarm.tvd.density import Density

# The peer's arena (main_phi5.py: env = [[-1.6, 1.6], [-1.0, 1.0]], the Robotarium's 3.2 m x
# 2 m) and its density "phi 5" (pyvoro2d.phi with two deviations): two bumps
# exp(-|q - m_k(t)|^2 / s^2), s = 0.3, whose centres circle with radius 0.3 around
# (-1.6/3, 0) counter-clockwise and (+1.6/3, 0) clockwise, t / tau radians at frame t,
# tau = 1500 / 2 pi. No floor: covswarm needs phi > 0, so FLOOR is added to ours.
ARENA = np.array([[-1.6, -1.0], [1.6, -1.0], [1.6, 1.0], [-1.6, 1.0]])
SPREAD, RADIUS, OFFSET, TAU = 0.3, 0.3, 1.6 / 3.0, 1500.0 / (2.0 * math.pi)
FLOOR = 1e-6
SAMPLES = 10_000  # the peer's Monte-Carlo points per cell (main_phi5.py's default)


def peer_density(t: float) -> Density:
    """The peer's phi 5 at frame t as a covswarm Density (rates per frame), plus FLOOR."""
    angle = t / TAU
    cos, sin = math.cos(angle), math.sin(angle)
    means = [[RADIUS * cos - OFFSET, RADIUS * sin], [RADIUS * cos + OFFSET, -RADIUS * sin]]
    rates = [[-RADIUS * sin / TAU, RADIUS * cos / TAU], [-RADIUS * sin / TAU, -RADIUS * cos / TAU]]
    variance = 0.5 * SPREAD**2  # exp(-d^2 / s^2) = exp(-d^2 / (2 sigma^2))
    return Density(
        floor=FLOOR,
        means=means,
        covariances=[np.eye(2) * variance] * 2,
        weights=[1.0, 1.0],
        mean_rates=rates,
        time=t,
    )


def layouts(sizes: list[int], count: int) -> list[np.ndarray]:
    """``count`` random layouts per size in the arena, kept 5 cm from its walls and rounded
    to the millimetre (the peer rounds positions to 1 mm)."""
    rng = np.random.default_rng(2026)
    return [
        np.round(rng.uniform([-1.55, -0.95], [1.55, 0.95], size=(n, 2)), 3)
        for n in sizes
        for _ in range(count)
    ]


def load_peer(folder: Path):
    """The peer's TVD (TVD-C) class, Agent and DoubleEllipse from its folder."""
    if not (folder / "coveragecontrol_2d.py").is_file():
        sys.exit(
            f"--peer {folder}: no coveragecontrol_2d.py there (the peer's "
            "pycoverage_robotarium folder)"
        )
    sys.path.insert(0, str(folder))
    import coveragecontrol_2d  # noqa: PLC0415 (the peer: on the path only now)
    import utils_2d  # noqa: PLC0415

    return coveragecontrol_2d, utils_2d


def peer_controller(peer, utils, positions: np.ndarray, samples: int):
    """A fresh peer TVD-C controller for ``positions``, set up as main_phi5.py sets it up."""
    frames = 1000
    trajectory = utils.DoubleEllipse(
        [10.0, 10.0], [0.0, 0.0],
        np.array([[0.3, 0.3], [0.6, 0.6]]), np.array([[0.3, 0.3], [0.6, 0.6]]),
        frames, 2, np.array([0.3, 0.3]), np.array([[-1.6 / 3.0, 0.0], [1.6 / 3.0, 0.0]]),
        np.array([[1, 0], [1, 0]]), np.array([[0, 1], [0, 1]]),
        np.array([0.3, 0.3]), np.array([0.3, 0.3]), frames / 2000,
    )  # fmt: skip
    params = {
        "env": [[-1.6, 1.6], [-1.0, 1.0]], "trim_vel": True, "seed": 0, "T": frames,
        "dt": 1, "t": 0, "num_frames": frames, "kappa": 1, "max_vel": 0.15,
        "mass_eps": 0, "num_points": samples, "tau": 2000,
    }  # fmt: skip
    agents = np.array([peer.Agent(p) for p in positions])
    return peer.TVD(params, trajectory, agents)


def two_hop(adjacency: list[set[int]], me: int) -> set[int]:
    known = {me} | adjacency[me]
    for j in adjacency[me]:
        known |= adjacency[j]
    return known


def first_quadrature():
    """The first implementation of the density integrals (Gauss rule on subdivided
    triangles), kept as the tests' reference: tests/density_reference.py."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from density_reference import QuadratureDensity  # noqa: PLC0415 (on the path only now)

    return QuadratureDensity


def measure(
    peer, utils, positions: np.ndarray, samples: int, repeats: int, quadrature=None
) -> dict:
    """One layout: the peer's full-team step per agent, our local steps (interleaved with and
    without the density, and with the first quadrature when given), our full-team TVD-C per
    agent, and the peer's centroid error."""
    n = len(positions)
    controller = peer_controller(peer, utils, positions, samples)
    controller.calculateVelocities(positions.T.copy())  # warms (first-call costs)
    peer_ms, frames = [], []
    for _ in range(repeats):
        start = time.perf_counter()
        controller.calculateVelocities(positions.T.copy())
        peer_ms.append((time.perf_counter() - start) * 1e3)
        frames.append(controller.t)
    # The peer's centroids at its last frame against the exact ones of the same density.
    exact = mass_centroid(positions, ARENA, peer_density(frames[-1]))[1]
    peer_error = np.linalg.norm(np.asarray(controller.centroid).reshape(n, 2) - exact, axis=1)
    density = peer_density(frames[-1])
    adjacency = neighbors(positions, ARENA)
    still = np.zeros_like(ARENA)
    models = {"uniform": None, "density": density}
    if quadrature is not None:
        models["quadrature"] = quadrature(density)
    ours: dict[str, list[float]] = {name: [] for name in models}
    for me in range(n):
        view = {j: positions[j] for j in two_hop(adjacency, me)}
        for name in tuple(models) * 3:  # the first of each warms
            # A fresh snapshot per step, as an agent makes one per tick: a snapshot keeps the
            # integrals of its last cells, which a step with the same view would reuse.
            phi = models[name]
            if name == "density":
                phi = density.at(density.time)
            elif name == "quadrature":
                phi = quadrature(density.at(density.time))
            start = time.perf_counter()
            local_step(me, view, ARENA, still, 1.0, density=phi)
            ours[name].append((time.perf_counter() - start) * 1e6)
    tvd_c(positions, ARENA, still, 1.0, density=density)  # warms
    team_ms = []
    for _ in range(repeats):
        start = time.perf_counter()
        tvd_c(positions, ARENA, still, 1.0, density=density)
        team_ms.append((time.perf_counter() - start) * 1e3)
    timed = {name: [x for i, x in enumerate(spent) if i % 3] for name, spent in ours.items()}
    density_us, uniform_us = timed["density"], timed["uniform"]
    first = {}
    if "quadrature" in timed:
        first["ours_local_first_quadrature_p50_us"] = float(np.percentile(timed["quadrature"], 50))
    return {
        "agents": n,
        "peer_step_ms": float(np.median(peer_ms)),
        "peer_per_agent_us": float(np.median(peer_ms)) * 1e3 / n,
        "peer_centroid_error_mm_median": float(np.median(peer_error)) * 1e3,
        "peer_centroid_error_mm_max": float(np.max(peer_error)) * 1e3,
        "ours_local_density_p50_us": float(np.percentile(density_us, 50)),
        "ours_local_uniform_p50_us": float(np.percentile(uniform_us, 50)),
        "ours_team_tvd_c_per_agent_us": float(np.median(team_ms)) * 1e3 / n,
        **first,
    }


def sizes_list(text: str) -> list[int]:
    """--sizes: positive integers separated by commas."""
    parts = text.split(",")
    if not all(p.strip().isdigit() and int(p) > 0 for p in parts):
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected positive integers separated by commas"
        )
    return [int(p) for p in parts]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--peer", type=Path, required=True, help="its pycoverage_robotarium folder")
    parser.add_argument("--sizes", type=sizes_list, default="5,10,20", help="team sizes")
    parser.add_argument("--layouts", type=int, default=3, help="random layouts per size")
    parser.add_argument("--repeats", type=int, default=3, help="peer steps timed per layout")
    parser.add_argument("--samples", type=int, default=SAMPLES, help="the peer's MC points")
    parser.add_argument("--out", type=Path, default=Path("runs/density-peer"))
    parser.add_argument(
        "--first-quadrature",
        action="store_true",
        help="also time our step with the first implementation (tests/density_reference.py)",
    )
    args = parser.parse_args()
    peer, utils = load_peer(args.peer)
    quadrature = first_quadrature() if args.first_quadrature else None
    sizes = args.sizes
    rows = []
    for positions in layouts(sizes, args.layouts):
        rows.append(measure(peer, utils, positions, args.samples, args.repeats, quadrature))
        print(json.dumps(rows[-1]), flush=True)
    summary = []
    for n in sizes:
        mine = [row for row in rows if row["agents"] == n]
        median = {key: float(np.median([row[key] for row in mine])) for key in mine[0]}
        # the worst cell of any layout, not the median of the layouts' worst
        median["peer_centroid_error_mm_max"] = max(r["peer_centroid_error_mm_max"] for r in mine)
        median["density_over_uniform"] = (
            median["ours_local_density_p50_us"] / median["ours_local_uniform_p50_us"]
        )
        median["peer_over_ours_density"] = (
            median["peer_per_agent_us"] / median["ours_local_density_p50_us"]
        )
        summary.append(median)
    args.out.mkdir(parents=True, exist_ok=True)
    result = {"settings": vars(args) | {"peer": str(args.peer), "out": str(args.out)}}
    (args.out / "peer.json").write_text(
        json.dumps(result | {"layouts": rows, "summary": summary}, indent=2) + "\n"
    )
    header = (
        "N  peer/agent us  ours local (phi) us  ours local (uniform) us  phi/uniform  "
        "peer/ours(phi)  ours TVD-C/agent us  peer centroid error mm (median, max of all layouts)"
    )
    print(header)
    for row in summary:
        print(
            f"{row['agents']:.0f}  {row['peer_per_agent_us']:.0f}  "
            f"{row['ours_local_density_p50_us']:.0f}  {row['ours_local_uniform_p50_us']:.0f}  "
            f"{row['density_over_uniform']:.2f}  {row['peer_over_ours_density']:.1f}  "
            f"{row['ours_team_tvd_c_per_agent_us']:.0f}  "
            f"{row['peer_centroid_error_mm_median']:.2f}, {row['peer_centroid_error_mm_max']:.2f}"
            + (
                f"  first quadrature {row['ours_local_first_quadrature_p50_us']:.0f} us"
                if "ours_local_first_quadrature_p50_us" in row
                else ""
            )
        )
    print(f"wrote {args.out / 'peer.json'}")


if __name__ == "__main__":
    main()
