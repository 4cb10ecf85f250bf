"""Viewer layouts for a run's channels: a top-down 3D panel beside two Plot panels.

Two files in docs/, both generated here (``python -m covswarm.records.layout docs``) and
checked against this module by the tests, so they never drift from the channels:

- ``foxglove-layout.json``: built with foxglove-sdk's ``foxglove.layouts`` (the Foxglove app).
- ``lichtblick-layout.json``: the same panels in the ``configById`` layout format that
  Lichtblick (and Foxglove Studio before 2.0) imports.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from covswarm.records.recorder import (
    AGENT_STATS_TOPIC,
    ARENA_TOPIC,
    CELLS_TOPIC,
    DOMAIN_TOPIC,
    ERROR_TOPIC,
    ROBOTS_TOPIC,
)
from covswarm.records.scene import FRAME

FOXGLOVE_FILE = "foxglove-layout.json"
LICHTBLICK_FILE = "lichtblick-layout.json"
SCENE_TOPICS = (ROBOTS_TOPIC, DOMAIN_TOPIC, CELLS_TOPIC, ARENA_TOPIC)
ERROR_PATH = f"{ERROR_TOPIC}.e_a"
# Team means of the agents' headline stats (coordinator.monitor.HEADLINE_STATS).
STATS_PATHS = (f"{AGENT_STATS_TOPIC}.mean.rate_hz", f"{AGENT_STATS_TOPIC}.mean.rx_per_s")
CAMERA_DISTANCE = 9.0  # m above the plane: a 5 m x 4 m arena fills the panel


def foxglove_layout() -> Any:
    """The layout as a ``foxglove.layouts.Layout`` (3D top-down view | e_a plot / stats plot)."""
    import foxglove.layouts as fl

    scene = fl.ThreeDeePanel(
        title="swarm",
        config=fl.ThreeDeeConfig(
            follow_tf=FRAME,
            follow_mode="follow-none",
            camera_state=fl.ThreeDeeCameraState(
                distance=CAMERA_DISTANCE, perspective=False, phi=0.0, theta_offset=90.0
            ),
            topics={
                topic: fl.BaseRendererSceneUpdateTopicSettings(visible=True)
                for topic in SCENE_TOPICS
            },
        ),
    )
    error = fl.PlotPanel(
        title="e_a (m)",
        config=fl.PlotConfig(
            paths=[fl.PlotSeries(value=ERROR_PATH, label="e_a")], show_legend=True
        ),
    )
    stats = fl.PlotPanel(
        title="agents (team mean)",
        config=fl.PlotConfig(paths=[fl.PlotSeries(value=p) for p in STATS_PATHS], show_legend=True),
    )
    plots = fl.SplitContainer(
        direction="column", items=[fl.SplitItem(content=error), fl.SplitItem(content=stats)]
    )
    return fl.Layout(
        content=fl.SplitContainer(
            direction="row",
            items=[
                fl.SplitItem(proportion=2, content=scene),
                fl.SplitItem(proportion=1, content=plots),
            ],
        )
    )


def lichtblick_layout() -> dict[str, Any]:
    """The same panels in the ``configById`` format (Lichtblick, Foxglove Studio 1.x)."""
    three_d = {
        "cameraState": {
            "distance": CAMERA_DISTANCE,
            "perspective": False,
            "phi": 0.0,
            "thetaOffset": 90.0,
            "target": [0, 0, 0],
            "targetOffset": [0, 0, 0],
            "targetOrientation": [0, 0, 0, 1],
            "fovy": 45,
            "near": 0.01,
            "far": 5000,
        },
        "followMode": "follow-none",
        "followTf": FRAME,
        "scene": {},
        "transforms": {},
        "topics": {topic: {"visible": True} for topic in SCENE_TOPICS},
        "layers": {},
        "publish": {"type": "point"},
        "imageMode": {},
    }

    def plot(paths: list[str]) -> dict[str, Any]:
        return {
            "paths": [
                {"value": p, "enabled": True, "timestampMethod": "receiveTime"} for p in paths
            ],
            "showLegend": True,
            "legendDisplay": "floating",
            "isSynced": True,
            "xAxisVal": "timestamp",
        }

    return {
        "configById": {
            "3D!covswarm": three_d,
            "Plot!error": plot([ERROR_PATH]),
            "Plot!agents": plot(list(STATS_PATHS)),
        },
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1},
        "layout": {
            "direction": "row",
            "first": "3D!covswarm",
            "second": {"direction": "column", "first": "Plot!error", "second": "Plot!agents"},
            "splitPercentage": 65,
        },
    }


def layout_files() -> dict[str, str]:
    """{file name: JSON text} of both layouts, pretty-printed and newline-terminated."""
    foxglove = json.loads(foxglove_layout().to_json())
    return {
        FOXGLOVE_FILE: json.dumps(foxglove, indent=2) + "\n",
        LICHTBLICK_FILE: json.dumps(lichtblick_layout(), indent=2) + "\n",
    }


def main(folder: str) -> None:
    """Write both layout files into ``folder`` (made if missing)."""
    Path(folder).mkdir(parents=True, exist_ok=True)
    for name, text in layout_files().items():
        (Path(folder) / name).write_text(text, encoding="utf-8")
        print(f"wrote {Path(folder) / name}")


if __name__ == "__main__":
    # the repository's docs/ by default, wherever it is run from
    main(sys.argv[1] if len(sys.argv) > 1 else str(Path(__file__).resolve().parent.parent / "docs"))
