"""``make readme-check``: run every command of the README's examples block, in order, as written.

The block is the first ```sh fence after the line starting "One runnable example each". Each command
line (comments and blank lines skipped; a trailing ``# ~N s`` is the time the README states) runs with
bash in a fresh temporary folder that has ``../shared`` linked to the real data, with ``.venv/bin`` first
on PATH, as a newcomer would run it from a checkout. Writes ``out/readme_check.json`` and
``out/readme_check.md`` (command, exit status, wall time, stated time) and exits 1 when any command
failed or took more than twice its stated time.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def example_commands(readme: Path) -> list[tuple[str, float | None]]:
    """(command, stated seconds or None) for each command line of the examples block."""
    lines = readme.read_text(encoding="utf-8").splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith("One runnable example each"))
    fence = next(i for i in range(start, len(lines)) if lines[i].startswith("```sh"))
    out = []
    for ln in lines[fence + 1:]:
        if ln.startswith("```"):
            break
        if not ln.strip() or ln.lstrip().startswith("#"):
            continue
        m = re.search(r"\s+#\s*~?\s*([\d.]+)\s*(s|min)\b.*$", ln)
        stated = None
        if m:
            stated = float(m.group(1)) * (60.0 if m.group(2) == "min" else 1.0)
            ln = ln[: m.start()]
        out.append((ln.strip(), stated))
    return out


def main() -> int:
    shared = (REPO / ".." / "shared").resolve()
    rows = []
    with tempfile.TemporaryDirectory(prefix="readme-check-") as tmp:
        work = Path(tmp) / "work"
        work.mkdir()
        if shared.is_dir():
            (Path(tmp) / "shared").symlink_to(shared)
        # the examples use models/motion paths relative to the checkout only through the README's own
        # fit-motion output, so nothing else is linked
        env = {**os.environ, "PATH": f"{REPO / '.venv' / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}",
               "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "PYOPENGL_PLATFORM": os.environ.get("PYOPENGL_PLATFORM", "egl"),
               "DEEPSLAM_PROGRESS": "0"}
        for cmd, stated in example_commands(REPO / "README.md"):
            print(f"$ {cmd}", flush=True)
            t0 = time.perf_counter()
            r = subprocess.run(["bash", "-c", cmd], cwd=work, env=env, capture_output=True, text=True)
            wall = time.perf_counter() - t0
            ok = r.returncode == 0 and (stated is None or wall <= 2 * stated)
            rows.append({"command": cmd, "exit_status": r.returncode, "wall_s": round(wall, 1), "stated_s": stated,
                         "ok": ok, "stderr_tail": r.stderr.strip().splitlines()[-1:] if r.returncode else []})
            print(f"  exit {r.returncode}, {wall:.1f} s" + (f" (stated {stated:g} s)" if stated else "")
                  + ("" if r.returncode == 0 else f": {r.stderr.strip().splitlines()[-1:]}"), flush=True)
    out = REPO / "out"
    out.mkdir(exist_ok=True)
    (out / "readme_check.json").write_text(json.dumps(rows, indent=2) + "\n")
    md = ["| command | exit | wall [s] | stated [s] |", "|---|---|---|---|"]
    md += [f"| `{r['command'][:90]}{'...' if len(r['command']) > 90 else ''}` | {r['exit_status']} | {r['wall_s']} | "
           f"{'' if r['stated_s'] is None else r['stated_s']:} |" for r in rows]
    (out / "readme_check.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return 0 if all(r["ok"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
