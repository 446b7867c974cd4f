#!/usr/bin/env python3
"""Reruns a campaign keeping the runs of the methods that did not change.

Usage: tools/reuse-runs.py --from OLD_FOLDER --methods M1,M2 [--rerun-kinds K1,K2
       --rerun-methods M1] -- aift campaign ARGS --out NEW

For regenerating results after a change that moves some methods' runs and provably not the
others' (a default of the u-AIC's prior moves the oracle and the hybrid, not the Kalman
baselines): it starts the campaign command, stops it as soon as it has written its journal's
header (which names the campaign, its fingerprint and this build), writes into that journal the
runs of the named methods from OLD_FOLDER/records.json (the same campaign file, methods and
seeds: its configuration digest must match), and runs the command again, which resumes from the
journal and runs only the other jobs (docs/campaigns.md, "Resuming"). Reaching tasks hold every
method's run, so they are kept only when every method is named. With --rerun-kinds, the runs
of --rerun-methods in cells of those fault kinds are rerun though the methods are named: for a
change that provably moves only runs of some kinds (one that acts only on ticks with a missing
reading moves only dropout cells).

The kept runs are the old build's: use it only for methods whose code and settings the change
does not touch, and check it (rerun a sample in full: the rows must be byte-identical). It
bypasses the journal's build check on purpose; the results folder's README says when it was
used.
"""
import argparse
import json
import os
import signal
import subprocess
import sys
import time


def journal_path(out):
    out = os.path.normpath(out)
    parent, name = os.path.split(out)
    return os.path.join(parent or ".", f".{name}.aift-journal")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--from", dest="old", required=True, help="a finished campaign folder")
    ap.add_argument("--methods", required=True, help="methods whose runs are kept, comma-separated")
    ap.add_argument(
        "--rerun-kinds",
        default="",
        help="fault kinds (campaign.csv's `kind`, comma-separated) whose cells are rerun for "
        "--rerun-methods even though those methods are kept elsewhere",
    )
    ap.add_argument("--rerun-methods", default="", help="methods --rerun-kinds applies to")
    ap.add_argument("command", nargs=argparse.REMAINDER, help="-- aift campaign ... --out NEW")
    a = ap.parse_args()
    cmd = a.command[1:] if a.command[:1] == ["--"] else a.command
    if "--out" not in cmd or cmd.index("--out") + 1 >= len(cmd):
        sys.exit("reuse-runs: the campaign command needs --out NEW")
    if "--shard" in cmd:
        sys.exit("reuse-runs: not for shards (run it on the whole campaign)")
    out = cmd[cmd.index("--out") + 1]
    journal = journal_path(out)
    if os.path.exists(journal):
        sys.exit(f"reuse-runs: {journal} exists (an interrupted run): resume or remove it first")
    keep = set(a.methods.split(","))
    with open(os.path.join(a.old, "records.json")) as f:
        old = json.load(f)
    if old.get("shard") != {"index": 1, "count": 1}:
        sys.exit(f"reuse-runs: {a.old} is a shard, not a whole campaign")

    # Start the campaign until its journal has a header, then stop it.
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 3600
    header = None
    while time.time() < deadline and p.poll() is None:
        if os.path.exists(journal):
            with open(journal) as f:
                line = f.readline()
            if line.endswith("\n"):
                header = json.loads(line)
                break
        time.sleep(0.2)
    if p.poll() is None:
        p.send_signal(signal.SIGTERM)
        p.wait()
    if header is None:
        sys.exit("reuse-runs: the campaign wrote no journal (did it fail? run it alone to see)")
    if header["config_digest"] != old.get("config_digest") or header["jobs"] != old.get("jobs"):
        sys.exit(
            f"reuse-runs: {a.old} is of another campaign configuration (digest "
            f"{old.get('config_digest')}, {old.get('jobs')} jobs; this one {header['config_digest']}, "
            f"{header['jobs']} jobs)"
        )
    methods = old["config"].get("methods") or []
    unknown = keep - {r["method"] for r in old["runs"]}
    if unknown:
        sys.exit(f"reuse-runs: {a.old} has no runs of {sorted(unknown)}")

    # Cells rerun for some methods: each run's cell kind from the old folder's campaign.csv,
    # whose run rows are in job order (checked run by run).
    rerun_kinds = {k for k in a.rerun_kinds.split(",") if k}
    rerun_methods = {m for m in a.rerun_methods.split(",") if m}
    if bool(rerun_kinds) != bool(rerun_methods):
        sys.exit("reuse-runs: --rerun-kinds and --rerun-methods go together")
    rerun_jobs = set()
    if rerun_kinds:
        import csv

        with open(os.path.join(a.old, "campaign.csv")) as f:
            rows = [r for r in csv.DictReader(f) if r["row"] == "run"]
        runs = sorted(old["runs"], key=lambda r: r["job"])
        if len(rows) != len(runs):
            sys.exit(f"reuse-runs: {a.old}/campaign.csv has {len(rows)} runs, records.json {len(runs)}")
        for row, r in zip(rows, runs):
            if row["method"] != r["method"] or int(row["seed"]) != r["seed"]:
                sys.exit(f"reuse-runs: {a.old}/campaign.csv's runs are not in job order (job {r['job']})")
            if row["kind"] in rerun_kinds and r["method"] in rerun_methods:
                rerun_jobs.add(r["job"])
        print(f"reuse-runs: {len(rerun_jobs)} runs of {sorted(rerun_methods)} in "
              f"{sorted(rerun_kinds)} cells rerun", file=sys.stderr)

    with open(journal) as f:
        lines = f.readlines()
    # Drop a torn last line; note the jobs the stopped run finished.
    while lines and not lines[-1].endswith("\n"):
        lines.pop()
    done = {json.loads(l)["job"] for l in lines[1:]}
    added = 0
    entries = []
    for r in old["runs"]:
        if r["method"] in keep and r["job"] not in done and r["job"] not in rerun_jobs:
            entries.append({"job": r["job"], "seconds": 0.0, "run": r})
    by_job = {}
    for r in old.get("reaching", []):
        by_job.setdefault(r["job"], []).append(r)
    all_kept = bool(methods) and set(methods) <= keep
    if all_kept:
        for j, rs in sorted(by_job.items()):
            if j not in done:
                entries.append({"job": j, "seconds": 0.0, "reaching": rs})
    with open(journal, "w") as f:
        f.writelines(lines)
        for e in entries:
            f.write(json.dumps(e, separators=(",", ":")) + "\n")
            added += 1
    print(f"reuse-runs: {added} jobs of {sorted(keep)} taken from {a.old}; running the rest",
          file=sys.stderr)
    sys.exit(subprocess.call(cmd))


if __name__ == "__main__":
    main()
