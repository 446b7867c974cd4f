#!/usr/bin/env python3
# The README's reaching table from a reaching campaign's reaching.csv: medians over the tasks per
# method, settling time over the tasks that settle. Usage: tools/reaching_summary.py results/reaching/reaching.csv
import csv, statistics as st, sys
rows=list(csv.DictReader(open(sys.argv[1])))
methods=[]
for r in rows:
    if r['method'] not in methods: methods.append(r['method'])
print("| method | belief RMSE (rad) | overshoot (%) | settling time (s) | steady-state error (rad) | tasks with an alarm |")
print("|---|---|---|---|---|---|")
for m in methods:
    rs=[r for r in rows if r['method']==m]
    f=lambda k: st.median(float(r[k]) for r in rs)
    settled=[float(r['settling_time']) for r in rs if r['settling_time'] not in ('','NaN','nan')]
    alarms=sum(1 for r in rs if int(r['false_alarms'])>0)
    print(f"| {m} | {f('belief_rmse'):.2e} | {f('overshoot_percent'):.1f} | {st.median(settled):.2f} ({len(settled)} settled) | {f('steady_state_error'):.1e} | {alarms} |")
