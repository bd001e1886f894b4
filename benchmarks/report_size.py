"""How big report.html is, what it is made of, and how long it takes to write.

Usage (any measured session; the demo makes one)::

    vastcal demo -o /tmp/demo -q
    OPENBLAS_NUM_THREADS=1 python benchmarks/report_size.py /tmp/demo/demo.h5

Prints the page's size split into the views (full-resolution JPEGs), the plots (matplotlib SVGs),
the embedded mesh (base64 float32/uint32), the inline scripts and CSS, and the rest; the mesh
triangles shown against measured; and the wall time of ``write_report`` (median of ``--repeat``).
"""

from __future__ import annotations

import argparse
import re
import statistics
import tempfile
import time
from pathlib import Path

from vastcal.report import write_report


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("session", type=Path, help="a measured session (vastcal run / vastcal demo)")
    ap.add_argument("--repeat", type=int, default=3, help="times to write the report (median time reported)")
    args = ap.parse_args()
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeat):
            t = time.perf_counter()
            page_path = write_report(args.session, Path(tmp) / f"r{i}")
            times.append(time.perf_counter() - t)
        page = page_path.read_text(encoding="utf-8")
    total = len(page.encode())
    parts = {
        "views (JPEG data URIs)": sum(len(m) for m in re.findall(r"data:image/jpeg;base64,[A-Za-z0-9+/=]+", page)),
        "plots (SVG data URIs)": sum(len(m) for m in re.findall(r"data:image/svg\+xml;base64,[A-Za-z0-9+/=]+", page)),
        "mesh (base64)": sum(
            len(m) for m in re.findall(r'<script type="application/octet-stream"[^>]*>([^<]*)<', page)
        ),
        "scripts (code)": sum(len(m) for m in re.findall(r"<script>(.*?)</script>", page, flags=re.S)),
        "outlines (SVG paths)": sum(len(m) for m in re.findall(r'<path d="([^"]*)"', page)),
        "CSS": sum(len(m) for m in re.findall(r"<style>(.*?)</style>", page, flags=re.S)),
    }
    n_views = len(re.findall(r'<figure class="view', page))
    shown = re.search(r'data-faces="(\d+)"', page)
    print(f"session            {args.session}")
    print(
        f"report.html        {total / 1e6:.2f} MB, {n_views} views, "
        f"mesh {shown.group(1) if shown else '?'} triangles shown"
    )
    for name, size in parts.items():
        print(f"  {name:<22} {size / 1e6:7.3f} MB  {100 * size / total:5.1f} %")
    rest = total - sum(parts.values())
    print(f"  {'text, tables, markup':<22} {rest / 1e6:7.3f} MB  {100 * rest / total:5.1f} %")
    print(f"write_report       median {statistics.median(times):.2f} s over {len(times)} (min {min(times):.2f} s)")


if __name__ == "__main__":
    main()
