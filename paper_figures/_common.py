"""Shared driver for the per-figure scripts: run the paper scene for one output."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main(output: str, doc: str, argv=None) -> str:
    ap = argparse.ArgumentParser(description=doc)
    ap.add_argument("--out", default=str(ROOT / "out" / "paper"), help="output folder")
    ap.add_argument("--scene", default=str(ROOT / "scenes" / "paper.toml"), help="scene file")
    ap.add_argument("--cache", default=str(ROOT / ".hapid_cache" / "stages"))
    a = ap.parse_args(argv)
    from hapid import scene

    cfg = scene.load_scene(a.scene)
    res = scene.run_scene(cfg, [output], out_dir=a.out, cache_dir=a.cache).results
    path = res[output] if isinstance(res[output], str) else str(Path(a.out) / "summary.md")
    print(path)
    return path


if __name__ == "__main__":  # pragma: no cover
    sys.exit("run one of the figN.py scripts")
