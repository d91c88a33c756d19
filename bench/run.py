"""``make bench``: runs every ``bench/bench_*.py`` and writes ``out/bench.json`` and ``out/bench.md``.

A benchmark module defines ``run(quick: bool) -> list[dict]``; each dict is one row with the keys
``name`` (what is measured), ``value``, ``unit``, ``baseline`` (name of the baseline measured in the
same run, or None), ``baseline_value``, ``ratio`` (value / baseline_value, or None), ``target`` (a
human-readable target such as ">= 15x", or None) and ``met`` (bool or None).
Speed is reported as ratios against baselines measured in the same run, never asserted in tests.
"""
from __future__ import annotations

import argparse
import importlib
import pkgutil
import platform
import sys
import time
from pathlib import Path

import bench as _bench
from bench.stamp import stamp
from deepslam.core import atomic


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="bench")
    ap.add_argument("--quick", action="store_true", help="smaller sizes, for a smoke run")
    ap.add_argument("--only", default=None, help="run only bench_<ONLY>")
    ap.add_argument("--out", default="out/bench.json")
    args = ap.parse_args(argv)
    rows: list[dict] = []
    for info in sorted(pkgutil.iter_modules(_bench.__path__), key=lambda m: m.name):
        if not info.name.startswith("bench_"):
            continue
        if args.only and info.name != f"bench_{args.only}":
            continue
        mod = importlib.import_module(f"bench.{info.name}")
        t0 = time.perf_counter()
        print(f"== {info.name}", flush=True)
        try:
            got = mod.run(quick=args.quick)
        except Exception as e:  # a broken benchmark must not hide the others
            got = [{"name": f"{info.name} FAILED", "value": None, "unit": "", "error": f"{type(e).__name__}: {e}"}]
        for r in got:
            r.setdefault("module", info.name)
            print(f"   {r['name']}: {r.get('value')} {r.get('unit', '')}"
                  + (f" (ratio {r['ratio']:.2f} vs {r.get('baseline')})" if r.get("ratio") is not None else ""), flush=True)
        rows.extend(got)
        print(f"   ({time.perf_counter() - t0:.1f} s)", flush=True)
    meta = {"python": sys.version.split()[0], "machine": platform.machine(), "processor": platform.processor(),
            "cpus": __import__("os").cpu_count(), "quick": args.quick, "time": time.strftime("%Y-%m-%dT%H:%M:%S"),
            **stamp()}
    out = Path(args.out)
    atomic.write_json(out, {"meta": meta, "results": rows})
    atomic.write_text(out.with_suffix(".md"), to_markdown(rows))
    print(f"wrote {out} and {out.with_suffix('.md')}")
    return 0


def _fmt(x) -> str:
    if x is None:
        return ""
    if isinstance(x, float):
        return f"{x:.4g}"
    return str(x)


def to_markdown(rows: list[dict]) -> str:
    lines = ["| benchmark | measure | value | unit | baseline | baseline value | ratio | target | met |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append("| " + " | ".join(_fmt(r.get(k)) for k in
                     ("module", "name", "value", "unit", "baseline", "baseline_value", "ratio", "target", "met")) + " |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
