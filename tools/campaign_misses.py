#!/usr/bin/env python3
"""Where one method misses a campaign's bars: cells the oracle recovers and it does not, cells
worse than no-FT, cells beyond 10x the oracle, alarms on healthy runs, and per method the cells
recovered where the oracle recovers. Usage: tools/campaign_misses.py campaign.csv [method]
(default hybrid) [--camera SENSITIVITY.tsv]. With --camera (the output of `cargo run --release
--example camera_sensitivity -- <the campaign's scenarios>`), every miss is annotated with its
faulted joint's camera sensitivity (the least over the scenario's poses, in encoder readings per
camera frame), the misses are counted by sensitivity band (below 1e-6 the camera cannot see the
joint at all), and the method's encoder bias, drift and gain cells are listed in the order of
S, the sensitivity per radian in camera sigmas (docs/method.md, "Sensors nobody else can
check")."""
import csv, sys, collections, os
args=sys.argv[1:]
camera={}
if '--camera' in args:
    i=args.index('--camera'); path=args[i+1]; del args[i:i+2]
    for r in csv.DictReader(open(path), delimiter='\t'):
        camera[(os.path.splitext(os.path.basename(r['scenario']))[0], int(r['joint']))]=(float(r['min_encoder_readings']), float(r['min_per_radian']))
sys.argv=[sys.argv[0]]+args
def joint_of(cell):
    ch=cell.split(' ')[0].lstrip('"')
    digits=ch.lstrip('abcdefghijklmnopqrstuvwxyz')
    return int(digits) if digits.isdigit() else None
def seen(arm,cell,per_radian=False):
    j=joint_of(cell)
    v=camera.get((arm,j)) if j is not None else None
    return None if v is None else v[1 if per_radian else 0]
def band(s):
    if s is None: return 'no joint'
    return 'camera-blind (<1e-6)' if s<1e-6 else 'seen'
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
for m in sorted(miss): print('  ',m, *([f'camera {seen(m[0],m[1]):.2e}'] if seen(m[0],m[1]) is not None else []))
if camera:
    cells_by_band=collections.Counter(band(seen(a,c)) for (a,c),d in by.items() if c!='healthy' and d.get('oracle',{}).get('verdict')=='recovered')
    miss_by_band=collections.Counter(band(seen(a,c)) for a,c,*_ in miss)
    for b in sorted(cells_by_band): print(f'  misses, {b}: {miss_by_band[b]} of {cells_by_band[b]} cells the oracle recovers')
    for kind in ('drift','bias','gain'):
        print(f'{focus}: encoder {kind} cells by camera sensitivity S (1/rad); verdict, final error (rad); oracle verdict')
        sel=[(seen(a,c,True),a,c,d) for (a,c),d in by.items() if c.startswith('enc') and joint_of(c) is not None and f' {kind} ' in c+' ' and focus in d]
        for S,a,c,d in sorted(sel, key=lambda t:(t[0] if t[0] is not None else -1, t[1], t[2])):
            S=S if S is not None else float('nan')
            print(f'   {a} {c:28s} S={S:7.3g}  {d[focus]["verdict"]:9s} {float(d[focus]["max_final_error"]):.3f}  oracle {d["oracle"]["verdict"]}')
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
