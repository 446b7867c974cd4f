#!/usr/bin/env python3
"""Summarises a campaign.csv by class of cell: fault site (encoder, tachometer, camera) x onset,
the two-fault pairs and the healthy cells, per method. Each entry is
`recovered (every seed) / cells; cells within 10x the oracle's post-fault MSE; median ratio to the
oracle`, and `Nw` when N cells are flagged worse than no-FT.

Usage: tools/campaign_classes.py results/campaign/campaign.csv [--by kind]
(`--by kind` groups by fault site x fault kind instead of onset). Standard library only.
"""
import csv
import statistics
import sys
from collections import OrderedDict, defaultdict


def site(channel, kind, cell):
    if kind == "healthy":
        return "healthy"
    if " then " in cell:
        first = cell.split()[0]
        return ("enc" if first.startswith("enc") else "tach") + " then cam (pair)"
    for p in ("enc", "tach", "cam"):
        if channel.startswith(p):
            return p
    return channel


def main():
    args = sys.argv[1:]
    if not args:
        sys.exit(__doc__)
    by = "onset"
    if "--by" in args:
        by = args[args.index("--by") + 1]
    rows = list(csv.DictReader(open(args[0])))
    cells = [r for r in rows if r["row"] == "cell"]
    methods = list(OrderedDict.fromkeys(r["method"] for r in cells))
    groups = defaultdict(lambda: defaultdict(list))
    for r in cells:
        s = site(r["channel"], r["kind"], r["cell"])
        key = s if s == "healthy" or "pair" in s else f"{s}, {r[by] or '-'}"
        groups[key][r["method"]].append(r)
    print("| class | cells | " + " | ".join(methods) + " |")
    print("|---|---|" + "---|" * len(methods))
    for key in sorted(groups):
        g = groups[key]
        n = len(next(iter(g.values())))
        out = []
        for m in methods:
            rs = g.get(m, [])
            rec = sum(r["verdict"] == "recovered" for r in rs)
            ratios = [float(r["ratio_to_oracle"]) for r in rs if r["ratio_to_oracle"]]
            w10 = sum(x <= 10.0 for x in ratios)
            worse = sum(r["worse_than_no_ft"] == "true" for r in rs)
            med = statistics.median(ratios) if ratios else float("nan")
            e = f"{rec}/{len(rs)}; {w10}; {med:.2g}"
            if worse:
                e += f"; {worse}w"
            out.append(e)
        print(f"| {key} | {n} | " + " | ".join(out) + " |")


if __name__ == "__main__":
    main()
