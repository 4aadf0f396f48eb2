"""``./vessel results``: the results page (``docs/results.md``) written from a demo's ``summary.json``.

The figures of a run live in its ``summary.json``; this renders them as Markdown tables (online per video and
for the paper's splits, the covariance's honesty, the offline pass) with the commit and command that made them,
so the page is regenerated after a run instead of edited by hand.

    ./vessel demo --out out/demo && ./vessel results out/demo/summary.json --out docs/results.md
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import subprocess
from collections.abc import Sequence
from pathlib import Path

from vessel_calib.params import atomic_write_text
from vessel_common.command_line import command_line_tool
from vessel_common.errors import DataError
from vessel_common.paths import repo_root

COLUMNS = ("set", "n", "m/100 m", "median m", "p80 m", "p80 % of range", "< 20 m", "coverage")


def _number(value, spec: str) -> str:
    return "-" if value is None or (isinstance(value, float) and not math.isfinite(value)) else format(value, spec)


def _row(name: str, block: dict) -> str:
    coverage = "-" if block.get("coverage") is None else \
        f"{100 * block['coverage']:.0f} % ({block['frames_covered']}/{block['frames_in_view']})"
    under = block.get("share_under_20m")
    cells = [name, str(block.get("n", "-")), _number(block.get("m_per_100m"), ".2f"),
             _number(block.get("median_m"), ".1f"), _number(block.get("p80_m"), ".1f"),
             _number(block.get("p80_pct"), ".1f"), "-" if under is None else f"{100 * under:.0f} %", coverage]
    return "| " + " | ".join(cells) + " |"


def score_table(scores: dict, per_video: bool = True) -> list[str]:
    """A Markdown table of one scoring block (``online`` or ``offline`` of a summary)."""
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    if per_video:
        lines += [_row(f"video {video}", block) for video, block in scores.get("per_video", {}).items()]
    lines += [_row(name, block) for name, block in scores.get("splits", {}).items()]
    return lines


def covariance_lines(covariance: dict) -> list[str]:
    """How often the published covariance's ellipses held the error, per split."""
    lines = []
    for name, block in covariance.get("splits", {}).items():
        if not block or not block.get("n"):
            continue
        lines.append(f"- {name}: {100 * block['inside_68']:.0f} / {100 * block['inside_95']:.0f} / "
                     f"{100 * block['inside_99']:.0f} % of {block['n']} errors inside their 68 / 95 / 99 % ellipses "
                     f"(mean NEES {block['nees_mean']:.2f}; honest: 68 / 95 / 99 % and 2)")
    return lines


def _commit() -> str:
    try:
        done = subprocess.run(["git", "-C", str(repo_root()), "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return done.stdout.strip() or "unknown"


def shape_problem(summary: dict) -> str | None:
    """What in ``summary`` is not laid out as ``./vessel demo`` writes it, or None: what ``render`` reads."""
    for name in ("online", "offline", "online_covariance"):
        scores = summary.get(name)
        if scores is None:
            continue
        if not isinstance(scores, dict):
            return f"'{name}' is not a block"
        for group in ("per_video", "splits"):
            blocks = scores.get(group, {})
            if not isinstance(blocks, dict) or not all(isinstance(b, dict) for b in blocks.values()):
                return f"'{name}.{group}' is not a block of blocks"
    runs = summary.get("runs") or []
    if not isinstance(runs, list) or not all(isinstance(run, dict) and "video" in run for run in runs):
        return "'runs' is not a list of runs"
    return None


def render(summary: dict, source: Path, title: str, command: str) -> str:
    """The page for one demo summary."""
    when = datetime.datetime.fromtimestamp(source.stat().st_mtime, tz=datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    lines = [f"# {title}", "",
             f"Written by `./vessel results {source} --out ...` from the demo's `summary.json` ({when}, commit "
             f"{_commit()}); do not edit by hand. The run: `{command}`. Errors are metres between the published "
             "position and the vessel's GPS at the frame's time; m/100 m is the paper's figure (least squares "
             "through the origin of error against range); coverage is the share of frames with the vessel in view "
             "that got a position.", ""]
    if "online" in summary:
        lines += ["## Live: what `/vessel/fix` published", ""] + score_table(summary["online"]) + [""]
    if summary.get("online_covariance"):
        lines += ["## Its covariance against its error", ""] + covariance_lines(summary["online_covariance"]) + [""]
    if summary.get("offline"):
        lines += ["## After the offline smoothing pass over the recorded tracks", ""]
        lines += score_table(summary["offline"]) + [""]
    runs = summary.get("runs") or []
    if runs:
        lines += ["## The runs", "", "| video | frames out / expected | seconds |", "|---|---|---|"]
        lines += [f"| {run['video']} | {run.get('frames_out')} / {run.get('frames_expected')} | "
                  f"{run.get('seconds')} |" for run in runs] + [""]
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    """The command line."""
    parser = argparse.ArgumentParser(prog="./vessel results", description=__doc__.split("\n\n")[0])
    parser.add_argument("summary", type=Path, help="summary.json written by ./vessel demo")
    parser.add_argument("--out", type=Path, default=None, help="Markdown page to write (default: print it)")
    parser.add_argument("--title", default="Results of ./vessel demo", help="the page's title")
    parser.add_argument("--command", default="./vessel demo", help="the command that made the summary")
    return parser


@command_line_tool
def main(argv: Sequence[str] | None = None) -> int:
    """Render the page; write it with ``--out``."""
    args = build_parser().parse_args(argv)
    try:
        summary = json.loads(args.summary.read_text())
    except FileNotFoundError:
        raise DataError(f"{args.summary} not found: run ./vessel demo first (it writes out/demo/summary.json)") \
            from None
    except (OSError, json.JSONDecodeError) as error:
        raise DataError(f"{args.summary} is not a demo summary ({error}); give out/DIR/summary.json") from None
    online = summary.get("online") if isinstance(summary, dict) else None
    if not isinstance(online, dict) or not (online.get("splits") or online.get("per_video")):
        raise DataError(f"{args.summary} has no 'online' scores: give the summary.json of ./vessel demo")
    wrong = shape_problem(summary)
    if wrong:
        raise DataError(f"{args.summary} is not a demo summary ({wrong}); give the summary.json of ./vessel demo")
    page = render(summary, args.summary, args.title, args.command)
    if args.out is None:
        print(page)
    else:
        atomic_write_text(args.out, page + "\n")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
