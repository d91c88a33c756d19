"""``make readme-check``: run every command block of the README and of docs/, in order, as written.

A block is a fenced ```sh or ```python block (```text and ```console blocks are shown, never run). The README
comes first, then docs/*.md in :data:`DOC_ORDER` (later pages use what earlier ones made, e.g. ``out/quick``).
Each shell command (comments and blank lines skipped, ``\\`` continuations joined; a trailing ``# ~N s`` or
``# ~N min`` is the time the page states) runs with bash, and each python block with the checkout's
interpreter, in a fresh copy of the checkout (tracked and untracked files, no out/ or .venv) with
``../shared`` linked to the real data and ``.venv/bin`` first on PATH, as a newcomer runs it. The set-up
commands (``make demo``, ``make test``, ``make ...``) are listed, not run. Writes ``out/readme_check.json``
and ``out/readme_check.md`` (page, command, exit status, wall time, stated time) and exits 1 when any
command failed or took more than twice its stated time.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DOC_ORDER = ("simulator.md", "plugins.md", "training.md", "api.md", "formats.md", "conventions.md", "models.md")
"""docs/ pages in the order they run (pages not named here follow, sorted)."""
SKIP = re.compile(r"^make(\s|$)")
"""Commands listed but not run: the set-up commands themselves."""


def pages() -> list[Path]:
    docs = REPO / "docs"
    named = [docs / n for n in DOC_ORDER if (docs / n).is_file()]
    rest = sorted(p for p in docs.glob("*.md") if p not in named and p.name != "results.md")
    return [REPO / "README.md", *named, *rest]


def blocks(page: Path) -> list[tuple[str, str, float | None]]:
    """(kind ``sh`` | ``python``, code, stated seconds or None) of each runnable unit of ``page``: one per
    shell command, one per python block."""
    lines = page.read_text(encoding="utf-8").splitlines()
    out, i = [], 0
    while i < len(lines):
        m = re.match(r"^```(\w+)\s*$", lines[i])
        if not m:
            i += 1
            continue
        kind, body = m.group(1), []
        i += 1
        while i < len(lines) and not lines[i].startswith("```"):
            body.append(lines[i])
            i += 1
        i += 1
        if kind == "python":
            out.append(("python", "\n".join(body), None))
        elif kind == "sh":
            joined, cur = [], ""
            for ln in body:
                cur = f"{cur} {ln.strip()}" if cur else ln
                if cur.rstrip().endswith("\\"):
                    cur = cur.rstrip()[:-1]
                    continue
                joined.append(cur)
                cur = ""
            for ln in joined:
                if not ln.strip() or ln.lstrip().startswith("#"):
                    continue
                stated = None
                t = re.search(r"\s+#\s*~?\s*([\d.]+)\s*(s|min)\b.*$", ln)
                if t:
                    stated = float(t.group(1)) * (60.0 if t.group(2) == "min" else 1.0)
                    ln = ln[: t.start()]
                out.append(("sh", ln.strip(), stated))
    return out


def _copy_checkout(dest: Path) -> None:
    files = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=REPO,
                           capture_output=True, text=True, check=True).stdout.split("\0")
    for f in filter(None, files):
        src = REPO / f
        if src.is_file():
            (dest / f).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / f)


def main() -> int:
    shared = (REPO / ".." / "shared").resolve()
    rows = []
    with tempfile.TemporaryDirectory(prefix="readme-check-") as tmp:
        work = Path(tmp) / "checkout"
        work.mkdir()
        _copy_checkout(work)
        if shared.is_dir():
            (Path(tmp) / "shared").symlink_to(shared)
        (work / ".venv").symlink_to(REPO / ".venv")
        env = {**os.environ, "PATH": f"{REPO / '.venv' / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}",
               "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "PYOPENGL_PLATFORM": os.environ.get("PYOPENGL_PLATFORM", "egl"),
               "DEEPSLAM_PROGRESS": "0"}
        for page in pages():
            for kind, code, stated in blocks(page):
                label = code.splitlines()[0][:100] if kind == "sh" else f"python block: {code.splitlines()[0][:80]}"
                print(f"[{page.relative_to(REPO)}] {label}", flush=True)
                if kind == "sh" and SKIP.match(code):
                    rows.append({"page": str(page.relative_to(REPO)), "command": code, "exit_status": None,
                                 "wall_s": None, "stated_s": stated, "ok": True, "note": "set-up command, not run"})
                    continue
                argv = ["bash", "-c", code] if kind == "sh" else [str(REPO / ".venv" / "bin" / "python"), "-c", code]
                t0 = time.perf_counter()
                r = subprocess.run(argv, cwd=work, env=env, capture_output=True, text=True)
                wall = time.perf_counter() - t0
                ok = r.returncode == 0 and (stated is None or wall <= 2 * stated)
                rows.append({"page": str(page.relative_to(REPO)), "command": label, "exit_status": r.returncode,
                             "wall_s": round(wall, 1), "stated_s": stated, "ok": ok,
                             "stderr_tail": r.stderr.strip().splitlines()[-1:] if r.returncode else []})
                print(f"  exit {r.returncode}, {wall:.1f} s" + (f" (stated {stated:g} s)" if stated else "")
                      + ("" if r.returncode == 0 else f": {r.stderr.strip().splitlines()[-1:]}"), flush=True)
    out = REPO / "out"
    out.mkdir(exist_ok=True)
    (out / "readme_check.json").write_text(json.dumps(rows, indent=2) + "\n")
    md = ["| page | command | exit | wall [s] | stated [s] |", "|---|---|---|---|---|"]
    md += [f"| {r['page']} | `{r['command'][:90]}{'...' if len(r['command']) > 90 else ''}` | "
           f"{'' if r['exit_status'] is None else r['exit_status']} | {'' if r['wall_s'] is None else r['wall_s']} | "
           f"{'' if r['stated_s'] is None else r['stated_s']} |" for r in rows]
    (out / "readme_check.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    failed = [r for r in rows if not r["ok"]]
    print(f"{len(rows) - len(failed)} of {len(rows)} commands ok")
    return 0 if not failed else 1


if __name__ == "__main__":
    sys.exit(main())
