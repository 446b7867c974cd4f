import itertools, json
import numpy as np
from scipy.signal import butter, filtfilt
from sets import SETS, tensor, TABLE3, TABLE3_NAMES, FRIC_LIN, PHI1, PHI2, PHI3, fric_sigmoid, fric_linear
from dyn import Model, load_matlab_fn, QMIN, QMAX

np.set_printoptions(suppress=True, linewidth=160)
OUT = {}
P = lambda *a: print(*a)
pct = lambda x, p: float(np.percentile(x, p))


# ------------------------------------------------------------ link extents from collision meshes
def stl_vertices(path):
    b = open(path, 'rb').read()
    n = np.frombuffer(b[80:84], np.uint32)[0]
    rec = np.dtype([('n', '<f4', 3), ('v', '<f4', (3, 3)), ('a', '<u2')])
    d = np.frombuffer(b[84:84 + n * 50], rec)
    return d['v'].reshape(-1, 3).astype(float)

EXT = []
for i in range(7):
    v = stl_vertices(f'data/stl/link{i+1}.stl')
    EXT.append(v.max(0) - v.min(0))
EXT = np.array(EXT)
LSIZE = EXT.max(1)
P('collision-mesh bbox extents [m] per link:\n', np.round(EXT, 3), '\nlink size (max extent):', np.round(LSIZE, 3))
OUT['link_size'] = LSIZE.tolist()

# ------------------------------------------------------------ per-link table
def principal(row):
    return np.sort(np.linalg.eigvalsh(tensor(row)))

P('\n=== per-link parameters ===')
for i in range(7):
    P(f'-- link {i+1}')
    for name, s in SETS.items():
        line = f'  {name:5s} m={s["m"][i]:8.4f}  c=({s["c"][i][0]:+.4f},{s["c"][i][1]:+.4f},{s["c"][i][2]:+.4f})'
        if s['I'] is not None:
            d = s['I'][i][:3]
            pm = principal(s['I'][i])
            line += f'  diag=({d[0]:.5f},{d[1]:.5f},{d[2]:.5f})  princ=({pm[0]:.5f},{pm[1]:.5f},{pm[2]:.5f})'
        P(line)
for name, s in SETS.items():
    P(f'{name}: arm mass (links1-7) = {s["m"].sum():.3f} kg')

# ------------------------------------------------------------ pairwise statistics
MASS_SETS = ['GAZ', 'MESH', 'FER', 'RICK', 'PYB']
INER_SETS = ['GAZ', 'MESH', 'FER']

def pair_stats(names, links=range(7)):
    rel_m, lr_m, dc_ax, dc_norm, dc_rel = [], [], [], [], []
    for a, b in itertools.combinations(names, 2):
        A, B = SETS[a], SETS[b]
        for i in links:
            rel_m.append(abs(A['m'][i] - B['m'][i]) / (0.5 * (A['m'][i] + B['m'][i])))
            lr_m.append(abs(np.log(A['m'][i] / B['m'][i])))
            if i == 0:   # c1z is 'don't care' in Gaz (filled by franka_ros) -> use x,y only
                ax = [0, 1]
            else:
                ax = [0, 1, 2]
            d = A['c'][i][ax] - B['c'][i][ax]
            dc_ax += list(np.abs(d)); dc_norm.append(np.linalg.norm(d)); dc_rel.append(np.linalg.norm(d) / LSIZE[i])
    return map(np.array, (rel_m, lr_m, dc_ax, dc_norm, dc_rel))

def vs_ref_stats(ref, names, links=range(7)):
    res = {}
    for b in names:
        A, B = SETS[ref], SETS[b]
        rel = [abs(B['m'][i] - A['m'][i]) / A['m'][i] for i in links]
        dcn = []
        for i in links:
            ax = [0, 1] if i == 0 else [0, 1, 2]
            dcn.append(np.linalg.norm(B['c'][i][ax] - A['c'][i][ax]))
        res[b] = (np.array(rel), np.array(dcn))
    return res

P('\n=== pairwise mass / CoM statistics (sets: %s) ===' % MASS_SETS)
rel_m, lr_m, dc_ax, dc_norm, dc_rel = pair_stats(MASS_SETS)
def summ(lbl, x, unit=''):
    P(f'  {lbl:42s} median {np.median(x):.3f}{unit}  p75 {pct(x,75):.3f}  p90 {pct(x,90):.3f}  max {x.max():.3f}  (n={len(x)})')
    return dict(median=float(np.median(x)), p75=pct(x, 75), p90=pct(x, 90), max=float(x.max()), n=len(x))
OUT['mass_rel_allpairs'] = summ('mass |dm|/mean', rel_m)
OUT['mass_logratio_allpairs'] = summ('mass |ln(ma/mb)|', lr_m)
OUT['com_axis_allpairs'] = summ('CoM |dc| per axis [m]', dc_ax)
OUT['com_norm_allpairs'] = summ('CoM ||dc|| [m]', dc_norm)
OUT['com_rel_allpairs'] = summ('CoM ||dc|| / link size', dc_rel)

P('\n  same, only the three complete sets GAZ/MESH/FER:')
rel_m3, lr_m3, dc_ax3, dc_norm3, dc_rel3 = pair_stats(INER_SETS)
OUT['mass_logratio_3'] = summ('mass |ln(ma/mb)|', lr_m3)
OUT['com_axis_3'] = summ('CoM |dc| per axis [m]', dc_ax3)
OUT['com_rel_3'] = summ('CoM ||dc|| / link size', dc_rel3)

P('\n  CAD-like sets only (MESH/FER/RICK/PYB) -- spread among non-identified estimates:')
rel_mc, lr_mc, dc_axc, dc_normc, dc_relc = pair_stats(['MESH', 'FER', 'RICK', 'PYB'])
OUT['mass_logratio_cad'] = summ('mass |ln(ma/mb)|', lr_mc)
OUT['com_axis_cad'] = summ('CoM |dc| per axis [m]', dc_axc)

P('\n  including FR3 (FR3 file, different robot): all pairs GAZ/MESH/FER/RICK/PYB/FR3')
r_, lr_, dca_, dcn_, dcr_ = pair_stats(MASS_SETS + ['FR3'])
OUT['mass_logratio_allpairs_fr3'] = summ('mass |ln(ma/mb)|', lr_)
OUT['com_axis_allpairs_fr3'] = summ('CoM |dc| per axis [m]', dca_)
r_, lr_, dca_, dcn_, dcr_ = pair_stats(['GAZ', 'FR3'])
OUT['mass_logratio_gaz_fr3'] = summ('GAZ vs FR3 mass |ln|', lr_)
OUT['com_axis_gaz_fr3'] = summ('GAZ vs FR3 CoM |dc| per axis [m]', dca_)
r_, lr_, dca_, dcn_, dcr_ = pair_stats(['MESH', 'FER', 'RICK', 'PYB', 'FR3'])
OUT['mass_logratio_cad_fr3'] = summ('CAD-like + FR3 mass |ln|', lr_)
OUT['com_axis_cad_fr3'] = summ('CAD-like + FR3 CoM |dc| per axis', dca_)

P('\n  each set vs GAZ (plant): per-link |dm|/m_GAZ and ||dc|| [m]')
for b, (r, d) in vs_ref_stats('GAZ', ['DELTA', 'MESH', 'FER', 'RICK', 'PYB', 'FR3']).items():
    P(f'   {b:5s} dm/m: {np.round(r,2)}  med {np.median(r):.2f} | dc: {np.round(d,3)} med {np.median(d):.3f}')

# inertia
P('\n=== inertia differences (GAZ/MESH/FER; link-1 xx,yy excluded: unidentifiable, GAZ values are artefacts) ===')
lr_diag, lr_pm, frob, lr_gyr = [], [], [], []
for a, b in itertools.combinations(INER_SETS, 2):
    A, B = SETS[a], SETS[b]
    for i in range(7):
        da, db = A['I'][i][:3], B['I'][i][:3]
        idx = [2] if i == 0 else [0, 1, 2]
        lr_diag += list(np.abs(np.log(da[idx] / db[idx])))
        lr_gyr += list(np.abs(np.log((da[idx] / A['m'][i]) / (db[idx] / B['m'][i]))))
        if i > 0:
            lr_pm += list(np.abs(np.log(principal(A['I'][i]) / principal(B['I'][i]))))
            Ta, Tb = tensor(A['I'][i]), tensor(B['I'][i])
            frob.append(np.linalg.norm(Ta - Tb) / (0.5 * (np.linalg.norm(Ta) + np.linalg.norm(Tb))))
lr_diag, lr_pm, frob, lr_gyr = map(np.array, (lr_diag, lr_pm, frob, lr_gyr))
def iner_pairs(names):
    xd, xp = [], []
    for a, b in itertools.combinations(names, 2):
        A, B = SETS[a], SETS[b]
        for i in range(7):
            idx = [2] if i == 0 else [0, 1, 2]
            xd += list(np.abs(np.log(A['I'][i][:3][idx] / B['I'][i][:3][idx])))
            if i > 0 and i < 6:
                xp += list(np.abs(np.log(principal(A['I'][i]) / principal(B['I'][i]))))
    return np.array(xd), np.array(xp)
OUT['inertia_diag_logratio'] = summ('diag |ln(Ia/Ib)|', lr_diag)
OUT['inertia_princ_logratio'] = summ('principal |ln| (links 2-7)', lr_pm)
OUT['inertia_frob_rel'] = summ('||Ia-Ib||_F / mean||I||_F (links 2-7)', frob)
OUT['inertia_per_mass_logratio'] = summ('diag(I)/m |ln ratio| (radius of gyr.^2)', lr_gyr)
xd, xp = iner_pairs(['GAZ', 'MESH', 'FER', 'FR3'])
OUT['inertia_diag_logratio_with_fr3'] = summ('diag |ln| GAZ/MESH/FER/FR3', xd)
xd, xp = iner_pairs(['GAZ', 'FR3'])
OUT['inertia_diag_logratio_gaz_fr3'] = summ('diag |ln| GAZ vs FR3', xd)
P('  MESH vs FER only (two CAD-like):')
x = []
for i in range(7):
    idx = [2] if i == 0 else [0, 1, 2]
    x += list(np.abs(np.log(SETS['MESH']['I'][i][:3][idx] / SETS['FER']['I'][i][:3][idx])))
OUT['inertia_diag_logratio_mesh_fer'] = summ('diag |ln| MESH vs FER', np.array(x))
P('  vs GAZ, per link diag ratios (set/GAZ):')
for b in ['MESH', 'FER', 'DELTA', 'FR3']:
    P(f'   {b}:', np.round(SETS[b]['I'][:, :3] / SETS['GAZ']['I'][:, :3], 2).tolist())

# ------------------------------------------------------------ base coefficients
P('\n=== base (identifiable) coefficients pi(p), Table III expressions ===')
pi_fn, pi_args = load_matlab_fn('data/get_Panda_coefficients_expanded.m', 'get_Panda_coefficients_expanded')

def pi_of(s):
    kw = {}
    for i in range(7):
        k = i + 1
        kw[f'm{k}'] = s['m'][i]
        for j, ax in enumerate('xyz'):
            kw[f'c{k}{ax}'] = s['c'][i][j]
        xx, yy, zz, xy, xz, yz = s['I'][i]
        kw.update({f'I{k}xx': xx, f'I{k}yy': yy, f'I{k}zz': zz, f'I{k}xy': xy, f'I{k}xz': xz, f'I{k}yz': yz})
    for f in ('fc', 'fo', 'fv'):
        for k in range(1, 8):
            kw[f'{f}{k}'] = 0.0
    return pi_fn(*[kw[a] for a in pi_args])[:43]

T3 = np.array([[np.nan if v is None else v for v in r] for r in TABLE3])
PI = dict(RE=T3[:, 0], PHAT_TAB=T3[:, 2], CLS=T3[:, 3], OSI=T3[:, 5])
for name in ['GAZ', 'DELTA', 'MESH', 'FER', 'FR3']:
    PI[name] = pi_of(SETS[name])
P('  check pi(GAZ) vs table pi(p-hat): max abs diff = %.4f' % np.nanmax(np.abs(PI['GAZ'] - PI['PHAT_TAB'])))
big = np.where(np.abs(PI['RE']) > 0.1)[0]
P('  significant coefficients (|pi_RE|>0.1):', [TABLE3_NAMES[k] for k in big])
P('  %-40s ' % 'coef' + ' '.join(f'{n:>8s}' for n in ['RE', 'CLS', 'OSI', 'GAZ', 'DELTA', 'MESH', 'FER', 'FR3']))
for k in big:
    P('  %-40s ' % TABLE3_NAMES[k] + ' '.join(f'{PI[n][k]:8.4f}' for n in ['RE', 'CLS', 'OSI', 'GAZ', 'DELTA', 'MESH', 'FER', 'FR3']))
OUT['base'] = {}
for a, b in [('RE', 'CLS'), ('RE', 'OSI'), ('CLS', 'OSI'), ('GAZ', 'DELTA'), ('GAZ', 'MESH'), ('GAZ', 'FER'), ('MESH', 'FER'),
             ('CLS', 'MESH'), ('CLS', 'FER'), ('GAZ', 'FR3'), ('CLS', 'FR3')]:
    r = np.abs(PI[a][big] - PI[b][big]) / np.abs(PI['RE'][big])
    OUT['base'][f'{a}-{b}'] = dict(median=float(np.median(r)), max=float(r.max()), vals=np.round(r, 3).tolist())
    P(f'  rel diff {a:5s} vs {b:5s} on significant coefs: median {np.median(r):.3f}  max {r.max():.3f}  {np.round(r,3)}')
grav = [k for k in range(31, 43) if abs(PI['RE'][k]) > 0.05]
P('  gravity (first-moment) coefs used:', [TABLE3_NAMES[k] for k in grav])
for a, b in [('RE', 'CLS'), ('RE', 'OSI'), ('GAZ', 'MESH'), ('GAZ', 'FER'), ('CLS', 'MESH'), ('CLS', 'FER'), ('GAZ', 'FR3'), ('CLS', 'FR3')]:
    r = np.abs(PI[a][grav] - PI[b][grav]) / np.abs(PI['RE'][grav])
    OUT['base'][f'grav {a}-{b}'] = dict(median=float(np.median(r)), max=float(r.max()))
    P(f'  gravity coefs rel diff {a} vs {b}: median {np.median(r):.3f} max {r.max():.3f}  {np.round(r,3)}')

# ------------------------------------------------------------ torque space, random configurations
P('\n=== torque-space differences on 2000 random configurations (arm only) ===')
rng = np.random.default_rng(1)
QS = rng.uniform(QMIN, QMAX, size=(2000, 7))
MODELS = {n: Model(SETS[n]) for n in ['GAZ', 'DELTA', 'MESH', 'FER', 'FR3']}
GG = {n: np.array([m.gravity(q) for q in QS]) for n, m in MODELS.items()}
MM = {n: np.array([m.mass_matrix(q) for q in QS[:400]]) for n, m in MODELS.items()}
OUT['torque'] = {}
def tq_metrics(G, M, Gref, Mref):
    g_rms = np.sqrt(((G - Gref) ** 2).mean(0)); g_ref = np.sqrt((Gref ** 2).mean(0))
    dM = np.sqrt(((np.einsum('kii->ki', M) - np.einsum('kii->ki', Mref)) ** 2).mean(0)) / np.sqrt((np.einsum('kii->ki', Mref) ** 2).mean(0))
    fro = np.median(np.linalg.norm(M - Mref, axis=(1, 2)) / np.linalg.norm(Mref, axis=(1, 2)))
    return g_rms, g_rms / g_ref, dM, fro
for n in ['DELTA', 'MESH', 'FER', 'FR3']:
    g_rms, g_rel, dM, fro = tq_metrics(GG[n], MM[n], GG['GAZ'], MM['GAZ'])
    OUT['torque'][n] = dict(g_rms=g_rms.tolist(), g_rel=g_rel.tolist(), Mdiag_rel=dM.tolist(), Mfro_med=float(fro))
    P(f'  {n:5s} vs GAZ  RMS dg [Nm] {np.round(g_rms,2)}\n         rel dg {np.round(g_rel,3)}\n         rel dM_ii {np.round(dM,3)}  median ||dM||_F/||M||_F {fro:.3f}')
P('  RMS g_GAZ [Nm]', np.round(np.sqrt((GG["GAZ"]**2).mean(0)), 2))
P('  RMS M_ii GAZ', np.round(np.sqrt((np.einsum("kii->ki", MM["GAZ"])**2).mean(0)), 4))

# ------------------------------------------------------------ real robot data (Gaz et al. exciting trajectory)
P('\n=== measured torques (exciting trajectory 1 of the Gaz et al. repository) ===')
t = np.loadtxt('data/exciting_traj_time.txt')
q = np.loadtxt('data/exciting_traj_positions.txt').reshape(-1, 7)
qd = np.loadtxt('data/exciting_traj_velocity.txt').reshape(-1, 7)
tau = np.loadtxt('data/exciting_traj_torques.txt').reshape(-1, 7)
tu = np.arange(t[0], t[-1], 0.001)
interp = lambda X: np.stack([np.interp(tu, t, X[:, j]) for j in range(7)], 1)
q, qd, tau = interp(q), interp(qd), interp(tau)
b, a = butter(2, 5.0 / 500.0)
qf, qdf, tauf = filtfilt(b, a, q, axis=0), filtfilt(b, a, qd, axis=0), filtfilt(b, a, tau, axis=0)
qdd = np.gradient(qdf, 0.001, axis=0)
sel = slice(500, len(tu) - 500, 5)
P(f'  samples used: {len(tu[sel])}, |qd|max {np.abs(qdf).max(0).round(2)}, |qdd|max {np.abs(qdd[sel]).max(0).round(2)}')
P('  RMS measured torque [Nm]', np.round(np.sqrt((tauf[sel] ** 2).mean(0)), 2))
OUT['real'] = {'tau_rms': np.sqrt((tauf[sel] ** 2).mean(0)).tolist()}
fr = np.array([fric_sigmoid(v) for v in qdf[sel]])
frl = np.array([fric_linear(v, 0) for v in qdf[sel]])
for n, m in MODELS.items():
    pred = np.array([m.rnea(a_, b_, c_) for a_, b_, c_ in zip(qf[sel], qdf[sel], qdd[sel])])
    for fl, F in [('sigmoid', fr), ('linCLS', frl), ('none', 0 * fr)]:
        e = np.sqrt(((tauf[sel] - pred - F) ** 2).mean(0))
        OUT['real'][f'{n}+{fl}'] = e.tolist()
        P(f'  {n:5s} + friction {fl:7s}: RMS err [Nm] {np.round(e,3)}  rel {np.round(e/np.sqrt((tauf[sel]**2).mean(0)),3)}')

# ------------------------------------------------------------ friction
P('\n=== friction ===')
for v in [0.05, 0.2, 0.5, 1.0, 1.5]:
    s = fric_sigmoid(np.full(7, v)); l = fric_linear(np.full(7, v), 0); o = fric_linear(np.full(7, v), 2)
    P(f'  qd={v:4.2f}: sigmoid {np.round(s,3)}\n            linCLS  {np.round(l,3)}\n            linOSI  {np.round(o,3)}')
P('  sigmoid saturation (Coulomb-like) phi1 - offset, +dir:', np.round(PHI1 - PHI1 / (1 + np.exp(-PHI2 * PHI3)), 3))
P('  sigmoid slope at qd=-phi3 (phi1*phi2/4) [Nm s/rad]:', np.round(PHI1 * PHI2 / 4, 3))
fv = np.array([r[0] for r in FRIC_LIN['fv']]); fvo = np.array([r[2] for r in FRIC_LIN['fv']])
fc = np.array([r[0] for r in FRIC_LIN['fc']]); fco = np.array([r[2] for r in FRIC_LIN['fc']])
P('  fv CLS', fv, ' OSI', fvo, '\n  |ln ratio| fv (j1-5,7)', np.round(np.abs(np.log(fv[[0,1,2,3,4,6]] / fvo[[0,1,2,3,4,6]])), 3))
P('  fc CLS', fc, ' OSI', fco, '\n  |ln ratio| fc', np.round(np.abs(np.log(fc / fco)), 3))
# linear vs sigmoid over the speed range used in the validation set (|qd| 0.1 .. 1 rad/s)
vs = np.linspace(0.1, 1.0, 10)
d = np.array([np.abs(fric_linear(np.full(7, v), 0) - fric_sigmoid(np.full(7, v))) / np.abs(fric_sigmoid(np.full(7, v))) for v in vs])
P('  |lin-sigmoid|/|sigmoid| over 0.1..1 rad/s: median per joint', np.round(np.median(d, 0), 2), ' overall median', round(float(np.median(d)), 2))
OUT['fric'] = dict(fc_lr=np.abs(np.log(fc / fco)).tolist(), fv_lr=np.abs(np.log(fv[[0,1,2,3,4,6]] / fvo[[0,1,2,3,4,6]])).tolist(),
                   lin_vs_sig_median=float(np.median(d)))
json.dump(OUT, open('results.json', 'w'), indent=1)
