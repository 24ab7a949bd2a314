"""`ratouch bench memory`: the peak memory of decoding one huge upload, per image mode, and of
16 at once, through the query's decode path (`QueryRequest.decode`: the visual crop and the
tactile frame, reduced to `QUERY_MAX_SIDE`), as `ratouch query` and the app decode them.

Each measurement runs in a fresh Python process, so one does not inherit another's freed
memory: the process imports the decode path, decodes a small upload (the baseline), resets
its peak (``/proc/self/clear_refs``; Linux), decodes the huge one(s), and reports its peak
resident set size (``VmHWM``) over the baseline, and the resident set after (whether memory
returns). Files are compressible (a gradient), as
small as an attacker's: a 7000 x 7000 16-bit PNG is about 100 KB on disk.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile

import numpy as np
from PIL import Image

#: The upload kinds measured: PIL mode of the file written, and what it is.
MODES = {"I;16": "16-bit grey PNG", "1": "1-bit PNG", "L": "8-bit grey PNG",
         "P": "palette PNG", "RGB": "8-bit RGB PNG", "CMYK": "CMYK TIFF", "F": "float TIFF"}


def write_upload(path: str, mode: str, side: int) -> str:
    """A `side` x `side` image of `mode` (a smooth gradient plus a grid), written to `path`."""
    ramp = np.linspace(0.0, 1.0, side, dtype=np.float32)
    plane = (ramp[None, :] * 0.7 + ramp[:, None] * 0.3)
    plane[::64] = 1.0  # a grid, so the image is not flat
    grey8 = (plane * 255).astype(np.uint8)
    if mode == "I;16":
        img = Image.fromarray((plane * 65535).astype(np.uint16))
    elif mode == "1":
        img = Image.fromarray(grey8 > 127)
    elif mode == "F":
        img = Image.fromarray(plane)
    else:
        img = Image.merge("RGB", [Image.fromarray(grey8)] * 3) if mode != "L" else \
            Image.fromarray(grey8)
        if mode == "P":
            img = img.convert("P")
        elif mode == "CMYK":
            img = img.convert("CMYK")
    img.save(path)
    return path


_CHILD = r"""
import gc, json, sys, threading
from ratouch.serve.request import QueryRequest

def status_mb(key):  # VmRSS now, VmHWM its peak (reset below; ru_maxrss survives exec)
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith(key + ":")) / 1024

small, paths, box = sys.argv[1], sys.argv[2:-1], json.loads(sys.argv[-1])
QueryRequest.decode(small, small)  # warm: imports, first allocations
gc.collect()
base = status_mb("VmRSS")
with open("/proc/self/clear_refs", "w") as f:
    f.write("5")  # the peak starts again from here
errors = []

def one(path):
    try:
        QueryRequest.decode(path, path, box=box)
    except Exception as e:  # reported, not raised: the figure is still measured
        errors.append(f"{type(e).__name__}: {e}")

threads = [threading.Thread(target=one, args=(p,)) for p in paths]
for t in threads:
    t.start()
for t in threads:
    t.join()
gc.collect()
print(json.dumps({"base_mb": round(base, 1),
                  "peak_over_base_mb": round(status_mb("VmHWM") - base, 1),
                  "after_over_base_mb": round(status_mb("VmRSS") - base, 1), "errors": errors}))
"""


def _measure(small: str, paths: list[str], box: list[int] | None) -> dict:
    """Decode `paths` at once in a fresh process; its memory figures (MB)."""
    out = subprocess.run([sys.executable, "-c", _CHILD, small, *paths, json.dumps(box)],
                         capture_output=True, text=True, check=False,
                         env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    if out.returncode != 0:
        raise RuntimeError(f"the measuring process failed: {out.stderr.strip()[-500:]}")
    return json.loads(out.stdout)


def bench_memory(side: int = 7000, burst: int = 16, modes: tuple[str, ...] = tuple(MODES),
                 box_side: int = 512) -> dict:
    """Peak memory of one `side` x `side` upload per mode (as both the visual image, with a
    `box_side` contact box, and the tactile image), and of `burst` 16-bit ones at once.

    Returns:
        {"side", "rows": [{"mode", "what", "file_kb", "peak_over_base_mb", ...}], "burst": {...}}
    """
    unknown = set(modes) - set(MODES)
    if unknown:
        raise ValueError(f"modes {sorted(unknown)} are not among {sorted(MODES)}")
    box = [side // 2 - box_side // 2, side // 2 - box_side // 2,
           side // 2 + box_side // 2, side // 2 + box_side // 2]
    rows = []
    with tempfile.TemporaryDirectory(prefix="ratouch-memory-") as tmp:
        small = write_upload(os.path.join(tmp, "small.png"), "RGB", 64)
        files = {}
        for mode in modes:
            ext = "tif" if mode in ("CMYK", "F") else "png"
            files[mode] = write_upload(os.path.join(tmp, f"{mode.replace(';', '')}.{ext}"),
                                       mode, side)
            r = _measure(small, [files[mode]], box)
            rows.append({"mode": mode, "what": MODES[mode],
                         "file_kb": round(os.path.getsize(files[mode]) / 1024, 1), **r})
        worst = files.get("I;16") or next(iter(files.values()))
        copies = [worst] * burst
        burst_r = {"n": burst, "mode": "I;16" if "I;16" in files else modes[0],
                   **_measure(small, copies, box)}
    return {"side": side, "box_side": box_side, "cpu_count": os.cpu_count(), "rows": rows,
            "burst": burst_r}


def format_memory(r: dict) -> str:
    """The figures as a table."""
    lines = [f"peak memory of one {r['side']}x{r['side']} upload, decoded as a query's visual "
             f"image ({r['box_side']} px box) and tactile image, over a small one's:",
             f"  {'mode':6} {'file':>10} {'peak +MB':>9} {'after +MB':>9}  what"]
    for row in r["rows"]:
        err = f"  (refused: {row['errors'][0]})" if row["errors"] else ""
        lines.append(f"  {row['mode']:6} {row['file_kb']:>8} KB {row['peak_over_base_mb']:>9} "
                     f"{row['after_over_base_mb']:>9}  {row['what']}{err}")
    b = r["burst"]
    lines.append(f"{b['n']} {b['mode']} uploads at once: peak +{b['peak_over_base_mb']} MB, "
                 f"+{b['after_over_base_mb']} MB after the burst"
                 + (f" ({len(b['errors'])} refused)" if b["errors"] else ""))
    return "\n".join(lines)
