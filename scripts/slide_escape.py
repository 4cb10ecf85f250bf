"""A robot stopped dead beside a still one, with and without its slide (covswarm.tvd.drive.
steer's ``slides``): the paths of one agent's robot that aims past a robot standing at the
safe distance, ANGLES off its aim.

Usage: .venv/bin/python scripts/slide_escape.py [--seconds 6] [--out docs/img/slide-escape.png]

One AgentBrain stepped at 10 Hz from START facing +x, where S (far to its right) puts its
aim; robot 1 stands 1 mm outside the safe distance, ``angle`` off that aim, and its
AgentState says so at every step. Each command is driven for its period (covswarm.tvd.drive.
integrate_one). Without the slide (the rule before 1 Dec 2026: a robot stopped dead faces
its aim) the brain's test for a stop is switched off. Prints, per angle and rule, the
closest approach and how far the robot got; draws the paths.
"""

from __future__ import annotations

import math
from contextlib import nullcontext
from pathlib import Path
from unittest import mock

import click

from covswarm import protocol
from covswarm.agent import brain as brain_module
from covswarm.agent.brain import AgentBrain, AgentConfig, SendCommand
from covswarm.tvd.drive import KHEPERA_IV, integrate_one
from covswarm.tvd.safety import body_safe_distance

WALL = 1.7e9  # s: the brain's wall clock at the start
START = (-0.2, 0.0)  # m: robot 0, facing +x
# S 2.2 m to robot 0's right: its cell is empty and it aims at S's centroid, along +x.
FAR_SQUARE = [[2.0, -1.0], [4.0, -1.0], [4.0, 1.0], [2.0, 1.0]]
SAFE = body_safe_distance(KHEPERA_IV.body_diameter, AgentConfig().safety_margin)  # 0.16 m
ANGLES = (0, 10, 30, 60, -40)  # degrees to the left of the aim
KAPPA = 0.1  # 1/s: an aim of ~0.32 m/s, the Khepera IV's cruising speed
PIN = 1.0  # s robot 0 stands at START: the brain follows robot 1 after the command timeout


def drive_past(
    angle: float, seconds: float = 6.0, slides: bool = True, also: tuple[float, ...] = ()
) -> tuple[AgentBrain, list[tuple[float, float, float]], tuple[float, float]]:
    """Brain 0 stepped at 10 Hz for ``seconds`` beside robot 1, a stranded robot (its robot's
    token alive, its agent's never seen: covswarm.agent.brain.AgentBrain.stranded) still 1
    mm outside the safe distance and ``angle`` rad to the left of robot 0's aim, and more
    such robots at the angles ``also``; (the brain, robot 0's poses (x, y, heading) every
    10 ms, robot 1's position). Robot 0 stands at START until the brain follows them (after
    the command timeout). ``slides``: False for the rule before."""
    still = [
        (START[0] + (SAFE + 1e-3) * math.cos(a), START[1] + (SAFE + 1e-3) * math.sin(a))
        for a in (angle, *also)
    ]
    config = AgentConfig(kappa=KAPPA, cmd_timeout=0.5)
    brain = AgentBrain(0, config)
    for rid in range(1, len(still) + 1):
        brain.on_liveliness("robot", rid, True)
    x, y, heading = *START, 0.0
    path = [(x, y, heading)]
    rule = (
        nullcontext()
        if slides
        else mock.patch.object(brain_module, "stopped_dead_one", lambda *args: False)
    )
    with rule:
        for k in range(round((seconds + PIN) / 0.1)):
            t, wall = 0.1 * k, WALL + 0.1 * k
            domain = protocol.Domain(
                seq=k + 1, stamp=wall, t=t, state="running", vertices=FAR_SQUARE,
                velocities=[[0.0, 0.0]] * 4, kappa=KAPPA,
            )  # fmt: skip
            brain.receive("domain", domain.encode(), t, wall)
            pose = protocol.Pose(id=0, x=x, y=y, theta=heading, stamp=wall, seq=k)
            brain.receive("pose", pose.encode(), t, wall, key_id=0)
            for rid, (sx, sy) in enumerate(still, start=1):
                other = protocol.Pose(id=rid, x=sx, y=sy, theta=0.0, stamp=wall, seq=k)
                brain.receive("stranded", other.encode(), t, wall, key_id=rid)
            brain.pace(0.1)
            (command,) = [a.command for a in brain.tick(t, wall) if isinstance(a, SendCommand)]
            if t < PIN:
                continue
            for _ in range(10):
                x, y, heading = integrate_one(x, y, heading, command.left, command.right, 0.01)
                path.append((x, y, heading))
    return brain, path, still[0]


def closest(path: list[tuple[float, float, float]], neighbour: tuple[float, float]) -> float:
    """m: the closest robot 0 came to robot 1 along ``path``."""
    return min(math.hypot(px - neighbour[0], py - neighbour[1]) for px, py, _ in path)


@click.command()
@click.option("--seconds", type=click.FloatRange(min=0.5), default=6.0, show_default=True)
@click.option("--out", type=click.Path(path_type=Path), default=Path("docs/img/slide-escape.png"))
def main(seconds: float, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, len(ANGLES), figsize=(3.2 * len(ANGLES), 3.4), sharey=True)
    print("| angle, deg | rule | closest, m | x after, m | steps slid |")
    print("|---|---|---|---|---|")
    for ax, degrees in zip(axes, ANGLES, strict=True):
        for slides, style in ((False, "C3--"), (True, "C0-")):
            brain, path, neighbour = drive_past(math.radians(degrees), seconds, slides)
            rule = "slide" if slides else "before"
            print(
                f"| {degrees} | {rule} | {closest(path, neighbour):.4f} | {path[-1][0]:+.3f} | "
                f"{brain.counters.slid} |"
            )
            xs, ys = [p[0] for p in path], [p[1] for p in path]
            label = "with its slide" if slides else "facing its aim: where it stays"
            ax.plot(xs, ys, style, marker=None if slides else "x", markevery=[-1], label=label)
        ax.add_patch(plt.Circle(neighbour, KHEPERA_IV.body_diameter / 2, color="0.4"))
        ax.add_patch(plt.Circle(neighbour, SAFE, fill=False, ls=":", color="0.4"))
        ax.add_patch(plt.Circle(START, KHEPERA_IV.body_diameter / 2, fill=False, color="C0"))
        ax.annotate("", xy=(START[0] + 0.25, START[1]), xytext=START,
                    arrowprops={"arrowstyle": "->", "color": "0.5"})  # fmt: skip
        ax.set_title(f"still robot {degrees} deg off the aim", fontsize=9)
        ax.set_xlim(-0.4, 0.8)
        ax.set_ylim(-0.45, 0.45)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
    axes[0].set_ylabel("y [m]")
    axes[0].legend(loc="lower left", fontsize=8)
    figure.suptitle(
        f"A robot stopped dead beside a still one (grey; dotted: the safe distance), {seconds:g} s"
        " at 10 Hz; its aim is along +x",
        fontsize=10,
    )
    figure.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out, dpi=110)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
