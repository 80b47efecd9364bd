"""The README's pictures of a result, made by the project's own code: a meshcat frame of the replay
(planner.view's self-contained page, photographed by headless chromium) and the result's plots.

    python -m scripts.readme_figures RESULT_DIR [--out docs/img] [--at 1.5]

Writes OUT/replay.png (800 x 600, the page paused at replay time AT [s]: `page.html#time=AT`, the same frame on
every run) and copies RESULT_DIR's foot_path.png and states.png to OUT. Needs Debian's chromium (apt-get install
chromium).
"""
from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from planner.result import write_atomically
from scripts._report import out_dir, run_main, script_parser

CHROMIUM_FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking",
    "--use-angle=swiftshader", "--enable-unsafe-swiftshader",  # WebGL on the CPU (no GPU needed)
    "--host-resolver-rules=MAP * ~NOTFOUND",  # the page is self-contained: nothing to fetch
    "--window-size=800,600", "--hide-scrollbars",
]


RENDER_BUDGET_MS = 2000  # virtual time for the page to load and seek before the screenshot [ms]


def main(argv=None) -> int:
    ap = script_parser(__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("result", type=Path, help="a result directory of planner plan / simulate")
    ap.add_argument("--out", type=out_dir, default=Path("docs/img"), help="where the pictures go [docs/img]")
    ap.add_argument("--at", type=float, default=1.5, help="the replay time [s] of the screenshot [1.5]")
    args = ap.parse_args(argv)
    if not 0.0 <= args.at < 1e6:  # nan gave a ValueError traceback
        ap.error(f"--at must be a number of seconds in [0, 1e6), got {args.at}")
    from planner.result import read_trajectory
    from planner.view import render_html

    end = float(read_trajectory(args.result)["t"][-1])
    if args.at > end:  # (the page showed its last frame, labelled with it, and the command said nothing)
        ap.error(f"--at {args.at:g} s is past the end of {args.result}'s replay, {end:.4g} s")
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        print("readme_figures: needs chromium on PATH (Debian: apt-get install chromium)", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    png = args.out / "replay.png"
    with tempfile.TemporaryDirectory() as tmp:
        page, shot = render_html(args.result, Path(tmp) / "replay.html"), Path(tmp) / "replay.png"
        # paused by the page itself at AT: a virtual-time budget of AT s gave another frame each run (1.58-1.77 s)
        run = subprocess.run([chromium, *CHROMIUM_FLAGS, f"--virtual-time-budget={RENDER_BUDGET_MS}",
                              f"--user-data-dir={Path(tmp) / 'profile'}", f"--screenshot={shot}", f"{page.as_uri()}#time={args.at!r}"],
                             capture_output=True, text=True, timeout=300)
        if run.returncode != 0 or not shot.is_file():  # (written beside the page: an earlier OUT/replay.png proves nothing)
            print(f"readme_figures: chromium made no screenshot:\n{run.stderr[-2000:]}", file=sys.stderr)
            return 1
        write_atomically(png, shot.read_bytes())
    copied = [name for name in ("foot_path.png", "states.png") if (args.result / name).is_file()]
    for name in copied:
        write_atomically(args.out / name, (args.result / name).read_bytes())
    print(f"wrote {png}" + (f" and {', '.join(copied)}" if copied else " (the result has no plots to copy)") + f" to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(run_main(main))
