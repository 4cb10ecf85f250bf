"""Refresh the figures of deterministic ``covswarm sim`` commands, in one command.

    python scripts/results.py            # rerun every command (a few minutes on 2 cores),
                                         # write docs/results.json and the pages' tables
    python scripts/results.py --render   # only rewrite the pages' tables from results.json

Every command below is one a reader can type; it is parsed by ``covswarm sim``'s own option
parser and run in-process (``simulate``, what ``covswarm sim`` runs, without the plots).
``--compare`` runs without dc/dt too (the run's name gets ``-noff``). docs/results.json keeps
each run's figures with its command, the date and the numpy/scipy versions; the tables
between ``<!-- results: NAME -->`` and ``<!-- /results -->`` in docs/*.md are rendered from it
and the README (tests/test_paper_claims.py checks that the pages match the file and that the
code still produces the file's figures).
"""

from __future__ import annotations

import argparse
import datetime
import json
import multiprocessing
import re
import shlex
from concurrent.futures import ProcessPoolExecutor
from importlib import metadata
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
RESULTS = DOCS / "results.json"

SCENARIOS = ("circle", "passage", "formation", "pinwheel")
COMMANDS: list[str] = [
    "covswarm sim --scenario circle --law d1 --compare --out runs/circle-d1",
    "covswarm sim --scenario circle --law c --damping 0 --compare --out runs/circle-c-exact",
    "covswarm sim --scenario circle --law c --prior zero --compare --out runs/circle-c-zero",
    "covswarm sim --scenario circle --law c --compare --out runs/circle-c",
    "covswarm sim --scenario circle --compare --out runs/circle-da",
    "covswarm sim --scenario passage --law d1 --compare --out runs/passage",
    "covswarm sim --scenario passage --compare --out runs/passage-da",
    *[
        f"covswarm sim --scenario {s} --law {law} --compare --out runs/laws/{s}-{law}"
        for s in SCENARIOS
        for law in ("d1", "c", "da")
    ],
    *[
        f"covswarm sim --scenario circle --law d1 --seed {s} --out runs/table1/seed{s}"
        for s in range(5)
    ],
    "covswarm sim --scenario formation --law d1 --compare --out runs/formation",
    "covswarm sim --scenario formation --compare --out runs/formation-da",
]


def runs_of(command: str) -> dict[str, dict]:
    """{run name: simulate() keyword options incl. "scenario"} of one ``covswarm sim`` command
    line, parsed by the command's own option parser (so a typo fails here)."""
    from covswarm.deploy.simulate import sim_command

    words = shlex.split(command)
    if words[:2] != ["covswarm", "sim"]:
        raise ValueError(f"not a covswarm sim command: {command!r}")
    with sim_command.make_context("sim", words[2:]) as ctx:
        p = dict(ctx.params)
    name = str(Path(p.pop("out_dir")).relative_to("runs"))
    compare, no_feedforward = p.pop("compare"), p.pop("no_feedforward")
    options = {"scenario": p.pop("scenario_name"), **p, "feedforward": not no_feedforward}
    runs = {name: options}
    if compare:
        runs[f"{name}-noff"] = {**options, "feedforward": False}
    return runs


def all_runs() -> dict[str, dict]:
    """Every run of COMMANDS by name, with the command that makes it."""
    runs = {}
    for command in COMMANDS:
        for name, options in runs_of(command).items():
            runs[name] = {"command": command, "options": options}
    return runs


def figures_of(options: dict) -> dict:
    """One run reduced to the figures its summary.json reports."""
    from covswarm.deploy.simulate import simulate
    from covswarm.mission.report import neighbor_histogram, steady_state_mean
    from covswarm.mission.scenario_files import load_scenario

    options = dict(options)
    result = simulate(load_scenario(options.pop("scenario")), **options)
    return {
        "e_a": float(steady_state_mean(result.t, result.error)),
        "final_error": float(result.error[-1]),
        "fallback_rate": result.fallbacks / (result.t.size - 1),
        "guarded": int(result.guarded),
        "neighbor_histogram": {
            str(k): v
            for k, v in sorted(neighbor_histogram(result.positions, result.final_polygon).items())
        },
    }


def measure(workers: int = 2) -> dict:
    """Run every distinct run once (identical options share one run), two at a time."""
    runs = all_runs()
    distinct: dict[str, str] = {}  # options as JSON -> first run name
    for name, run in runs.items():
        distinct.setdefault(json.dumps(run["options"], sort_keys=True), name)
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(workers, mp_context=context) as pool:
        futures = {
            key: pool.submit(figures_of, runs[name]["options"]) for key, name in distinct.items()
        }
        done = {key: future.result() for key, future in futures.items()}
    return {
        "date": datetime.date.today().isoformat(),
        "refresh": "python scripts/results.py",
        "versions": {p: metadata.version(p) for p in ("numpy", "scipy")},
        "runs": {
            name: {"command": run["command"], **done[json.dumps(run["options"], sort_keys=True)]}
            for name, run in runs.items()
        },
    }


# ---------------------------------------------------------------- tables


def _m(value: float) -> str:
    """A steady-state e_a in m: 4 decimals, 5 below a millimetre."""
    return f"{value:.5f} m" if value < 1e-3 else f"{value:.4f} m"


def _gain(runs: dict, name: str, without: str) -> str:
    return f"{100 * (1 - runs[name]['e_a'] / runs[without]['e_a']):.1f} %"


def _guard(run: dict) -> str:
    if run["fallback_rate"] > 0:
        return f"fell back on {100 * run['fallback_rate']:.1f} % of steps"
    return str(run["guarded"])


def _circle(runs: dict) -> list[str]:
    rows = [
        ("TVD-D1", "circle-d1", "0.0562 m vs 0.1248 m, 55 %"),
        ("TVD-C exact (`--damping 0`), falls back to TVD-D1", "circle-c-exact", "–"),
        ("TVD-C, feedforward damped toward 0 (`--prior zero`)", "circle-c-zero", "–"),
        ("TVD-C, feedforward damped toward v(p) (default `c`)", "circle-c", "–"),
        ("**TVD-DA** (`da`, the default)", "circle-da", "–"),
    ]
    lines = [
        "| law | steady-state e_a with dc/dt | without | improvement | "
        "guard / fallback (with dc/dt) | paper (TVD-D1) |",
        "|---|---|---|---|---|---|",
    ]
    for label, name, paper in rows:
        run, off = runs[name], runs[f"{name}-noff"]
        lines.append(
            f"| {label} | {_m(run['e_a'])} | {_m(off['e_a'])} | "
            f"{_gain(runs, name, f'{name}-noff')} | {_guard(run)} | {paper} |"
        )
    return lines


def _passage(runs: dict) -> list[str]:
    return [
        "| | with dc/dt | without | improvement | TVD-DA (`da`), with dc/dt |",
        "|---|---|---|---|---|",
        f"| `covswarm sim` (unicycle) | {_m(runs['passage']['e_a'])} | "
        f"{_m(runs['passage-noff']['e_a'])} | {_gain(runs, 'passage', 'passage-noff')} | "
        f"{_m(runs['passage-da']['e_a'])} |",
        "| paper (real robots) | 0.0323 m | 0.057 m | 43.3 % | – |",
    ]


def _laws(runs: dict) -> list[str]:
    labels = {
        "circle": "circle, 100 single integrators, translating",
        "passage": "passage, 10 Khepera IV, translating and scaling",
        "formation": "formation, 20, moving density",
        "pinwheel": "pinwheel, 30 Khepera IV, turning, orbiting, shrinking",
    }
    lines = [
        "| scenario | TVD-D1 (`d1`) | TVD-C (`c`, damped) | TVD-DA (`da`) | "
        "without dc/dt (d1 and da) | d1 / da |",
        "|---|---|---|---|---|---|",
    ]
    for s, label in labels.items():
        d1, c, da = (runs[f"laws/{s}-{law}"]["e_a"] for law in ("d1", "c", "da"))
        ratio = d1 / da
        lines.append(
            f"| {label} | {_m(d1)} | {_m(c)} | {_m(da)} | "
            f"{_m(runs[f'laws/{s}-d1-noff']['e_a'])} | {ratio:.{1 if ratio < 10 else 0}f} |"
        )
    return lines


def table_1(runs: dict) -> dict[int, float]:
    """Mean over seeds 0-4 of how many robots have k neighbours, k = 1..8."""
    seeds = [runs[f"table1/seed{s}"]["neighbor_histogram"] for s in range(5)]
    return {k: sum(h.get(str(k), 0) for h in seeds) / len(seeds) for k in range(1, 9)}


def _table_1(runs: dict) -> list[str]:
    mean = table_1(runs)
    return [
        "| neighbours | " + " | ".join(str(k) for k in mean) + " |",
        "|---" * 9 + "|",
        "| covswarm (mean of 5) | " + " | ".join(f"{v:.1f}" for v in mean.values()) + " |",
        "| paper (mean of 5) | – | 2.6 | 3 | 28.6 | 9 | 50.4 | 6.4 | – |",
    ]


def _formation(runs: dict) -> list[str]:
    d1, off, da = (runs[n]["e_a"] for n in ("formation", "formation-noff", "formation-da"))
    return [
        "| law | with dc/dt | without | improvement | TVD-DA (`da`) | d1 / da |",
        "|---|---|---|---|---|---|",
        f"| TVD-D1 (`d1`), both terms of Proposition 1 | {_m(d1)} | {_m(off)} | "
        f"{_gain(runs, 'formation', 'formation-noff')} | {_m(da)} | {d1 / da:.1f} |",
    ]


TABLES = {
    "circle": _circle,
    "passage": _passage,
    "laws": _laws,
    "table1": _table_1,
    "formation": _formation,
}
BLOCK = re.compile(r"(<!-- results: (\w+) -->\n)(.*?)(<!-- /results -->)", re.DOTALL)


def render(text: str, results: dict) -> str:
    """``text`` with every results block rewritten from ``results`` (docs/results.json)."""

    def table(match: re.Match) -> str:
        name = match.group(2)
        if name not in TABLES:
            raise ValueError(f"no table named {name!r} (known: {sorted(TABLES)})")
        lines = TABLES[name](results["runs"])
        footer = (
            f"*Measured on {results['date']} (numpy {results['versions']['numpy']}, scipy "
            f"{results['versions']['scipy']}); refresh: `{results['refresh']}`.*"
        )
        return match.group(1) + "\n".join([*lines, "", footer]) + "\n" + match.group(4)

    return BLOCK.sub(table, text)


def pages() -> list[Path]:
    """The documentation pages (and the README) that hold a results block."""
    candidates = [ROOT / "README.md", *sorted(DOCS.glob("*.md"))]
    return [p for p in candidates if BLOCK.search(p.read_text(encoding="utf-8"))]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--render", action="store_true", help="only rewrite the tables")
    args = parser.parse_args()
    if not args.render:
        results = measure()
        RESULTS.write_text(json.dumps(results, indent=1, sort_keys=True) + "\n")
    results = json.loads(RESULTS.read_text())
    for page in pages():
        page.write_text(render(page.read_text(encoding="utf-8"), results), encoding="utf-8")
        print(f"wrote {page.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
