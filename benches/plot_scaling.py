#!/usr/bin/env python3
"""The `scaling` workload's JSON lines as a log-log SVG plot, with no plotting library.

    cargo run --release --example workloads -- scaling > scaling.jsonl
    python3 benches/plot_scaling.py scaling.jsonl docs/scaling.svg

Three panels (insert ns per row, latest-at ns per query, range ns per row), each with the
store's rows on the x axis and one curve per shape and arrival order; both axes are
logarithmic, so a flat curve is a constant cost and a straight rising one a power of the
size (slope 1: linear), which the legend states as the fitted exponent.
"""

import json
import math
import sys

PANELS = [("insert", "insert, ns per row"), ("latest_at", "latest-at, ns per query"),
          ("range", "range, ns per row visited")]
COLOURS = {("chunks10", "in_order"): "#1f77b4", ("chunks10", "out_of_order"): "#ff7f0e",
           ("stream", "in_order"): "#2ca02c", ("stream", "out_of_order"): "#d62728"}
WIDTH, HEIGHT, MARGIN = 330, 300, 55


def load(path):
    series = {}
    with open(path) as f:
        for line in f:
            line = line.strip()
            if not line.startswith("{"):
                continue
            r = json.loads(line)
            if r.get("workload") != "scaling":
                continue
            key = (r["phase"], r["shape"], r["arrival"])
            series.setdefault(key, []).append((r["rows"], r["ns_per_op"]))
    return {k: sorted(v) for k, v in series.items()}


def slope(points):
    """Least-squares exponent of ns against rows on log-log axes."""
    if len(points) < 2:
        return 0.0
    xs = [math.log10(x) for x, _ in points]
    ys = [math.log10(max(y, 1e-3)) for _, y in points]
    mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
    den = sum((x - mx) ** 2 for x in xs)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / den if den else 0.0


def panel(series, phase, title, left):
    curves = {k[1:]: v for k, v in series.items() if k[0] == phase}
    points = [p for v in curves.values() for p in v]
    if not points:
        return []
    x_lo = math.floor(math.log10(min(x for x, _ in points)))
    x_hi = math.ceil(math.log10(max(x for x, _ in points)))
    y_lo = math.floor(math.log10(max(min(y for _, y in points), 1e-2)))
    y_hi = math.ceil(math.log10(max(y for _, y in points)))
    y_hi = max(y_hi, y_lo + 1)
    w, h = WIDTH - MARGIN - 10, HEIGHT - 2 * MARGIN

    def px(x):
        return left + MARGIN + (math.log10(x) - x_lo) / (x_hi - x_lo) * w

    def py(y):
        return MARGIN + h - (math.log10(max(y, 1e-2)) - y_lo) / (y_hi - y_lo) * h

    out = [f'<text x="{left + MARGIN + w / 2}" y="{MARGIN - 25}" text-anchor="middle" '
           f'font-weight="bold">{title}</text>',
           f'<rect x="{left + MARGIN}" y="{MARGIN}" width="{w}" height="{h}" fill="none" '
           f'stroke="#888"/>']
    for e in range(x_lo, x_hi + 1):
        x = px(10 ** e)
        out.append(f'<line x1="{x}" y1="{MARGIN}" x2="{x}" y2="{MARGIN + h}" stroke="#eee"/>')
        out.append(f'<text x="{x}" y="{MARGIN + h + 15}" text-anchor="middle">10^{e}</text>')
    for e in range(y_lo, y_hi + 1):
        y = py(10 ** e)
        out.append(f'<line x1="{left + MARGIN}" y1="{y}" x2="{left + MARGIN + w}" y2="{y}" '
                   f'stroke="#eee"/>')
        out.append(f'<text x="{left + MARGIN - 5}" y="{y + 4}" text-anchor="end">10^{e}</text>')
    out.append(f'<text x="{left + MARGIN + w / 2}" y="{MARGIN + h + 32}" '
               f'text-anchor="middle">rows in the store</text>')
    for i, (key, pts) in enumerate(sorted(curves.items())):
        colour = COLOURS.get(key, "#000")
        path = " ".join(f"{px(x):.1f},{py(y):.1f}" for x, y in pts)
        out.append(f'<polyline points="{path}" fill="none" stroke="{colour}" stroke-width="2"/>')
        for x, y in pts:
            out.append(f'<circle cx="{px(x):.1f}" cy="{py(y):.1f}" r="3" fill="{colour}"/>')
        ly = MARGIN + h + 48 + 14 * i
        out.append(f'<rect x="{left + MARGIN}" y="{ly - 9}" width="10" height="10" '
                   f'fill="{colour}"/>')
        out.append(f'<text x="{left + MARGIN + 15}" y="{ly}">{key[0]} {key[1]}: '
                   f'slope {slope(pts):.2f}</text>')
    return out


def main():
    if len(sys.argv) != 3:
        sys.exit("usage: plot_scaling.py SCALING.jsonl OUT.svg")
    series = load(sys.argv[1])
    if not series:
        sys.exit(f"plot_scaling.py: no scaling lines in {sys.argv[1]}")
    total_h = HEIGHT + 70
    body = []
    for i, (phase, title) in enumerate(PANELS):
        body += panel(series, phase, title, i * WIDTH)
    svg = (f'<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH * len(PANELS) + 20}" '
           f'height="{total_h}" font-family="sans-serif" font-size="11">'
           f'<rect width="100%" height="100%" fill="white"/>' + "".join(body) + "</svg>\n")
    with open(sys.argv[2], "w") as f:
        f.write(svg)


if __name__ == "__main__":
    main()
