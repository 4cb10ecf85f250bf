"""When in a run the agents missed their deadlines, from its recording.

Usage: .venv/bin/python scripts/missed_deadlines.py RUN_DIR [--rate 10] [--start 5]

Reads RUN_DIR/run.mcap: the agents' stats (``/agents/stats``, about once a second: each
agent's ``missed_deadline``, the fraction of its mission periods so far whose command went
out late) and the first e_a sample (``/error``), taken as the mission's start. The missed
periods per agent so far are estimated as the team's mean fraction x rate x mission time
(the stats carry fractions, not counts). Prints one JSON document: the estimate at every
stats sample, by ``--start`` s, by the end, and after ``--start`` s.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from mcap.reader import make_reader


def missed_periods(samples: list[tuple[float, float]], rate: float) -> list[tuple[float, float]]:
    """(mission time s, periods missed per agent so far) from (mission time s, mean missed
    fraction) samples: fraction x rate x time, 0 before the start."""
    return [(t, fraction * rate * max(t, 0.0)) for t, fraction in samples]


def split_at(counts: list[tuple[float, float]], start: float) -> tuple[float, float, float]:
    """From ``missed_periods``: the periods missed per agent by the last sample up to
    ``start`` s, by the end, and after ``start`` (their difference, not below 0: the
    estimate is not exact, the stats being up to a second old when recorded)."""
    early = ([n for t, n in counts if t <= start] or [0.0])[-1]
    final = counts[-1][1] if counts else 0.0
    return early, final, max(final - early, 0.0)


def read_samples(mcap_path: Path) -> list[tuple[float, float]]:
    """(mission time s, team's mean missed fraction) of each ``/agents/stats`` message."""
    stats, start = [], None
    with mcap_path.open("rb") as stream:
        for _, channel, message in make_reader(stream).iter_messages(
            topics=["/agents/stats", "/error"]
        ):
            if channel.topic == "/error":
                start = message.log_time if start is None else min(start, message.log_time)
            else:
                agents = json.loads(message.data)["agents"]
                if agents:
                    fraction = sum(a["missed_deadline"] for a in agents) / len(agents)
                    stats.append((message.log_time, fraction))
    if start is None:
        raise SystemExit(f"{mcap_path}: no /error sample, so no mission start")
    return [((log_time - start) / 1e9, fraction) for log_time, fraction in stats]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a covswarm run's output folder")
    parser.add_argument("--rate", type=float, default=10.0, help="control rate, Hz")
    parser.add_argument("--start", type=float, default=5.0, help="s counted as the start")
    args = parser.parse_args()
    if not (args.run / "run.mcap").is_file():
        parser.error(f"{args.run}: no run.mcap there (a covswarm run's output folder)")
    counts = missed_periods(read_samples(args.run / "run.mcap"), args.rate)
    early, final, late = split_at(counts, args.start)
    print(
        json.dumps(
            {
                "missed_per_agent": [[round(t, 1), round(n, 2)] for t, n in counts],
                f"by_{args.start:g}_s": round(early, 2),
                "by_end": round(final, 2),
                f"after_{args.start:g}_s": round(late, 2),
            }
        )
    )


if __name__ == "__main__":
    main()
