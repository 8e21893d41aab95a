"""``apac-mj screenshot``: a PNG of a recording in the real Rerun viewer, headless."""
from __future__ import annotations

import argparse
from pathlib import Path

DESCRIPTION = """\
Open a recording (.rrd) in the real Rerun viewer on a virtual display
(xvfb-run) and save what it shows as a PNG, then exit. The virtual screen is
sized so that its pointer rests outside the viewer's window: no hover tooltip
covers the arm (with xvfb-run's own screen every screenshot had one). Needs
xvfb-run and a Vulkan or OpenGL driver; on Debian or Ubuntu:

  apt-get install -y xvfb mesa-vulkan-drivers

Software rendering is slow: a screenshot takes 10-20 s.

examples:
  apac-mj record --task changing_target --agent apac --episodes 5 --out rollout.rrd
  apac-mj screenshot rollout.rrd --out shot.png
  apac-mj screenshot rollout.rrd --out wide.png --window-size 1920x1080
"""


def register(sub: argparse._SubParsersAction) -> None:
    from apac_mj.recording.screenshot import DEFAULT_TIMEOUT_S, DEFAULT_WINDOW

    p = sub.add_parser("screenshot", help="save a PNG of a recording in the Rerun viewer, headless (xvfb-run)",
                       description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("rrd", type=Path, help="the recording (.rrd) to show")
    p.add_argument("--out", type=Path, default=Path("shot.png"), help="the PNG to write (default shot.png)")
    p.add_argument("--window-size", default=f"{DEFAULT_WINDOW[0]}x{DEFAULT_WINDOW[1]}",
                   help=f"the viewer window, WIDTHxHEIGHT (default {DEFAULT_WINDOW[0]}x{DEFAULT_WINDOW[1]}; "
                        "the PNG may be drawn at twice that)")
    p.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT_S,
                   help=f"seconds the viewer may take (default {DEFAULT_TIMEOUT_S:.0f})")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from apac_mj.recording.screenshot import parse_window_size, screenshot

    png = screenshot(args.rrd, args.out, parse_window_size(args.window_size), args.timeout)
    print(f"wrote {png} ({png.stat().st_size / 1e3:.0f} KB)")
    return 0
