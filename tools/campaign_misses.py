#!/usr/bin/env python3
"""Where one method misses a campaign's bars: cells the oracle recovers and it does not, cells
worse than no-FT, cells beyond 10x the oracle, alarms on healthy runs, and per method the cells
recovered where the oracle recovers. Usage: tools/campaign_misses.py campaign.csv [method]
(default hybrid)."""
import csv, sys, collections
rows=list(csv.DictReader(open(sys.argv[1])))
cells=[r for r in rows if r['row']=='cell']
runs=[r for r in rows if r['row']=='run']
by=collections.defaultdict(dict)
for r in cells: by[(r['arm'],r['cell'])][r['method']]=r
methods=sorted({r['method'] for r in cells})
focus=sys.argv[2] if len(sys.argv)>2 else 'hybrid'
miss=[];worse=[];beyond=[]
for (arm,cell),d in by.items():
    if cell=='healthy': continue
    o=d.get('oracle'); h=d.get(focus)
    if not o or not h: continue
    if o['verdict']=='recovered' and h['verdict']!='recovered': miss.append((arm,cell,h['verdict'],h['max_final_error'],h['ratio_to_oracle']))
    if h['worse_than_no_ft']=='true': worse.append((arm,cell,h['ratio_to_oracle']))
    try:
        if float(h['ratio_to_oracle'])>10: beyond.append((arm,cell,h['ratio_to_oracle']))
    except: beyond.append((arm,cell,h['ratio_to_oracle']))
print(f'{focus}: misses where oracle recovers: {len(miss)}')
for m in sorted(miss): print('  ',m)
print(f'{focus}: worse than no-ft: {len(worse)}')
for m in sorted(worse): print('  ',m)
print(f'{focus}: beyond 10x: {len(beyond)}; by kind', collections.Counter(c.split(' ')[1] if ' ' in c else c for a,c,_ in beyond))
print('by channel type', collections.Counter(c.split(' ')[0].rstrip('0123456789') for a,c,_ in beyond))
al=collections.defaultdict(list)
for r in runs:
    if r['cell']=='healthy' and int(r['false_alarms'] or 0)>0: al[r['method']].append((r['arm'],r['seed'],r['false_alarms']))
for m in methods: print('healthy alarms', m, len(al[m]), al[m][:12])
orec=collections.Counter(); 
for m in methods:
    n=sum(1 for (a,c),d in by.items() if c!='healthy' and d.get('oracle',{}).get('verdict')=='recovered' and d.get(m,{}).get('verdict')=='recovered')
    print('recovers where oracle does', m, n)
print('oracle fails', sum(1 for (a,c),d in by.items() if c!='healthy' and d['oracle']['verdict']!='recovered'))
