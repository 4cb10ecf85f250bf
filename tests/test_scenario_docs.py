"""The TOML examples of docs/scenarios.md load as written: a reader who copies one gets a
mission, not a refusal."""

from __future__ import annotations

import re
from pathlib import Path

from covswarm.mission.scenario_files import load_scenario, scenario_from_dict, tomllib

DOC = (Path(__file__).resolve().parents[1] / "docs" / "scenarios.md").read_text(encoding="utf-8")
BLOCKS = re.findall(r"```toml\n(.*?)```", DOC, flags=re.DOTALL)


def test_the_first_example_is_a_whole_mission_that_loads(tmp_path: Path) -> None:
    path = tmp_path / "zigzag.toml"
    path.write_text(BLOCKS[0], encoding="utf-8")
    scenario = load_scenario(str(path))
    assert scenario.name == "zigzag" and scenario.agents == 10
    assert len(scenario.world.obstacles) == 1


def test_every_domain_example_loads_in_the_first_examples_mission() -> None:
    # The other blocks show a [domain] table (and keys beside it) in place of the first's.
    base = tomllib.loads(BLOCKS[0])
    for block in BLOCKS[1:]:
        part = tomllib.loads(block)
        if "domain" not in part or "name" in part:
            continue
        data = {**base, **part}
        data.pop("obstacles", None)  # the first's box is placed for the zigzag's S only
        data.pop("initial", None)
        scenario_from_dict(data, base=Path(__file__).resolve().parents[1] / "scenarios")
