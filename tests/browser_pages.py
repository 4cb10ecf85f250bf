"""What the console's browser tests share: Debian's Chromium (never a Playwright download),
``covswarm console`` on a free port, and reading the page's map."""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from contextlib import contextmanager

from live_runs import stop_process

from covswarm.deploy.plan import covswarm_argv

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
VIEWPORT = {"width": 1100, "height": 700}


@contextmanager
def console(endpoint: str, swarm: str, *args: str) -> Iterator[str]:
    """``covswarm console`` on a free port; yields the URL it printed."""
    process = subprocess.Popen(
        [*covswarm_argv(), "console", "--connect", endpoint, "--swarm", swarm, "--port", "0",
         *args],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    try:
        line = process.stdout.readline()
        assert "http://" in line, f"console printed {line!r}"
        yield line[line.index("http://") :].strip()
    finally:
        stop_process(process)


# The 9 x 9 canvas pixels around world point (x, y), as RGBA bytes (a JS expression's prelude).
_PATCH = """
  const map = document.getElementById("map"), box = map.getBoundingClientRect();
  const [cx, cy] = window.covswarm.clientXY(x, y), dpr = window.devicePixelRatio || 1;
  const px = Math.round((cx - box.left) * dpr) - 4, py = Math.round((cy - box.top) * dpr) - 4;
  const data = map.getContext("2d").getImageData(px, py, 9, 9).data;"""
# Mean colour (r, g, b, 0-255) of a 9 x 9 pixel patch of the map around a world point.
COLOUR = f"""([x, y]) => {{{_PATCH}
  const sum = [0, 0, 0];
  for (let i = 0; i < data.length; i += 4) for (let c = 0; c < 3; c++) sum[c] += data[i + c];
  return sum.map((s) => s / (data.length / 4));
}}"""
# The largest blue-over-green excess (0-255) of a pixel in the same 9 x 9 pixels: a line
# of the route's purple (#8e44ad: 105) covers at least one of them whole wherever it
# crosses, which the patch's mean dilutes by the line's angle and offset.
BLUE_OVER_GREEN = f"""([x, y]) => {{{_PATCH}
  let most = -255;
  for (let i = 0; i < data.length; i += 4) most = Math.max(most, data[i + 2] - data[i + 1]);
  return most;
}}"""


def open_page(browser, url: str):
    page = browser.new_page(viewport=VIEWPORT)
    page.goto(url)
    page.wait_for_function(
        "window.covswarm.world() !== null && window.covswarm.state() !== null"
        " && window.covswarm.state().polygon.length >= 3",
        timeout=20000,
    )
    return page
