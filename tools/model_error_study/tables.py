import numpy as np
from sets import SETS, tensor
ORDER=['GAZ','DELTA','MESH','FER','RICK','PYB','FR3']
def pm(r): return np.sort(np.linalg.eigvalsh(tensor(r)))
print('| link | set | m [kg] | CoM x,y,z [m] | Ixx, Iyy, Izz (at CoM) [kg m²] | principal moments [kg m²] |')
print('|---|---|---|---|---|---|')
for i in range(7):
    for n in ORDER:
        s=SETS[n]; c=s['c'][i]
        if s['I'] is None: d='—'; p='—'
        else:
            d=', '.join(f'{x:.4g}' for x in s['I'][i][:3]); p=', '.join(f'{x:.3g}' for x in pm(s['I'][i]))
        print(f'| {i+1} | {n} | {s["m"][i]:.4g} | {c[0]:+.4f}, {c[1]:+.4f}, {c[2]:+.4f} | {d} | {p} |')
print()
print('| set | '+' | '.join(f'L{i}' for i in range(1,8))+' | arm total |')
print('|---|'+'---|'*8)
for n in ORDER:
    s=SETS[n]; print(f'| {n} | '+' | '.join(f'{x:.3g}' for x in s['m'])+f' | {s["m"].sum():.2f} |')
print()
print('| set vs GAZ | '+' | '.join(f'L{i}' for i in range(1,8))+' | median |')
print('|---|'+'---|'*8)
for n in ['DELTA','MESH','FER','RICK','PYB','FR3']:
    r=SETS[n]['m']/SETS['GAZ']['m']
    print(f'| m ratio {n} | '+' | '.join(f'{x:.2f}' for x in r)+f' | — |')
for n in ['DELTA','MESH','FER','RICK','PYB','FR3']:
    d=[np.linalg.norm((SETS[n]['c'][i]-SETS['GAZ']['c'][i])[[0,1] if i==0 else [0,1,2]])*100 for i in range(7)]
    print(f'| ‖Δc‖ cm {n} | '+' | '.join(f'{x:.1f}' for x in d)+f' | {np.median(d):.1f} |')
