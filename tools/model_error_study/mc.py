"""Monte-Carlo: what torque-space error does a given per-link parameter error produce?
Perturb the plant (GAZ p-hat) and compare with the spread between credible published sets."""
import json, sys
import numpy as np
from scipy.signal import butter, filtfilt
from sets import SETS, tensor, fric_sigmoid
from dyn import R0, P, QMIN, QMAX, G0, Model

np.set_printoptions(suppress=True, linewidth=160)


def rotz_b(q):
    c, s = np.cos(q), np.sin(q)
    R = np.zeros(q.shape + (3, 3)); R[..., 0, 0] = c; R[..., 0, 1] = -s; R[..., 1, 0] = s; R[..., 1, 1] = c; R[..., 2, 2] = 1
    return R


def rnea_b(m, c, I, q, qd, qdd, g=G0):
    """batched RNEA. m (7,), c (7,3), I (7,3,3); q,qd,qdd (N,7) -> tau (N,7)"""
    N = q.shape[0]
    R = [R0[i] @ rotz_b(q[:, i]) for i in range(7)]            # (N,3,3)
    w = np.zeros((N, 3)); wd = np.zeros((N, 3)); a = np.tile([0, 0, g], (N, 1)).astype(float)
    z = np.array([0, 0, 1.0]); F = []; Nn = []
    for i in range(7):
        Rt = np.swapaxes(R[i], 1, 2)
        a = np.einsum('nij,nj->ni', Rt, a + np.cross(wd, P[i]) + np.cross(w, np.cross(w, P[i])))
        wr = np.einsum('nij,nj->ni', Rt, w)
        wd = np.einsum('nij,nj->ni', Rt, wd) + np.cross(wr, qd[:, i:i + 1] * z) + qdd[:, i:i + 1] * z
        w = wr + qd[:, i:i + 1] * z
        ac = a + np.cross(wd, c[i]) + np.cross(w, np.cross(w, c[i]))
        F.append(m[i] * ac)
        Nn.append(wd @ I[i].T + np.cross(w, w @ I[i].T))
    tau = np.zeros((N, 7)); f = None; n = None
    for i in reversed(range(7)):
        if f is None:
            n = Nn[i] + np.cross(c[i], F[i]); f = F[i]
        else:
            fc = np.einsum('nij,nj->ni', R[i + 1], f)
            n = Nn[i] + np.einsum('nij,nj->ni', R[i + 1], n) + np.cross(c[i], F[i]) + np.cross(P[i + 1], fc)
            f = fc + F[i]
        tau[:, i] = n[:, 2]
    return tau


def params(s):
    return s['m'].copy(), s['c'].copy(), np.array([tensor(r) for r in s['I']])


def mass_b(m, c, I, q):
    Ms = np.zeros((q.shape[0], 7, 7)); z = np.zeros_like(q)
    for j in range(7):
        e = np.zeros_like(q); e[:, j] = 1
        Ms[:, :, j] = rnea_b(m, c, I, q, z, e, g=0.0)
    return Ms


def perturb(m, c, I, sm, sc, sI, rng, scale_c_by_size=None):
    m2 = m * np.exp(sm * rng.standard_normal(7))
    if scale_c_by_size is None:
        c2 = c + sc * rng.standard_normal((7, 3))
    else:
        c2 = c + sc * scale_c_by_size[:, None] * rng.standard_normal((7, 3))
    I2 = np.empty_like(I)
    for i in range(7):
        lam, V = np.linalg.eigh(I[i])
        for _ in range(100):
            l2 = lam * np.exp(sI * rng.standard_normal(3))
            if l2[0] + l2[1] >= l2[2] and l2[0] + l2[2] >= l2[1] and l2[1] + l2[2] >= l2[0]:
                break
        I2[i] = V @ np.diag(l2) @ V.T
    return m2, c2, I2


if __name__ == '__main__':
    # validate batched RNEA
    rng = np.random.default_rng(3)
    Q = rng.uniform(QMIN, QMAX, (5, 7)); QD = rng.normal(0, 1, (5, 7)); QDD = rng.normal(0, 2, (5, 7))
    g = Model(SETS['GAZ']); m, c, I = params(SETS['GAZ'])
    ref = np.array([g.rnea(a, b, d) for a, b, d in zip(Q, QD, QDD)])
    print('batched RNEA max abs diff vs scalar:', np.abs(rnea_b(m, c, I, Q, QD, QDD) - ref).max())

    LS = np.array(json.load(open('results.json'))['link_size'])
    # configurations and real data
    QS = rng.uniform(QMIN, QMAX, (1000, 7))
    t = np.loadtxt('data/exciting_traj_time.txt')
    rd = lambda f: np.loadtxt(f).reshape(-1, 7)
    q, qd, tau = rd('data/exciting_traj_positions.txt'), rd('data/exciting_traj_velocity.txt'), rd('data/exciting_traj_torques.txt')
    tu = np.arange(t[0], t[-1], 0.001)
    it = lambda X: np.stack([np.interp(tu, t, X[:, j]) for j in range(7)], 1)
    q, qd, tau = it(q), it(qd), it(tau)
    b, a = butter(2, 5.0 / 500.0)
    q, qd, tau = filtfilt(b, a, q, axis=0), filtfilt(b, a, qd, axis=0), filtfilt(b, a, tau, axis=0)
    qdd = np.gradient(qd, 0.001, axis=0)
    sel = slice(500, len(tu) - 500, 5)
    q, qd, qdd, tau = q[sel], qd[sel], qdd[sel], tau[sel]
    fr = fric_sigmoid(qd)
    mg, cg, Ig = params(SETS['GAZ'])
    G_ref = rnea_b(mg, cg, Ig, QS, 0 * QS, 0 * QS)
    M_ref = mass_b(mg, cg, Ig, QS[:300])
    g_rms = np.sqrt((G_ref ** 2).mean(0))
    Mii_ref = np.sqrt((np.einsum('kii->ki', M_ref) ** 2).mean(0))
    real_gaz = np.sqrt(((tau - rnea_b(mg, cg, Ig, q, qd, qdd) - fr) ** 2).mean(0))

    def metrics(m, c, I):
        G = rnea_b(m, c, I, QS, 0 * QS, 0 * QS)
        M = mass_b(m, c, I, QS[:300])
        dg = np.sqrt(((G - G_ref) ** 2).mean(0)) / g_rms
        dM = np.sqrt(((np.einsum('kii->ki', M) - np.einsum('kii->ki', M_ref)) ** 2).mean(0)) / Mii_ref
        fro = np.median(np.linalg.norm(M - M_ref, axis=(1, 2)) / np.linalg.norm(M_ref, axis=(1, 2)))
        real = np.sqrt(((tau - rnea_b(m, c, I, q, qd, qdd) - fr) ** 2).mean(0))
        return dg, dM, fro, real

    out = {}
    print('\nreference points (set vs GAZ): rel dg j2-6 | rel dM_ii j1-7 | ||dM||F rel | real-data RMS err ratio to GAZ j1-7')
    for n in ['DELTA', 'MESH', 'FER', 'FR3']:
        dg, dM, fro, real = metrics(*params(SETS[n]))
        out[n] = dict(dg=dg.tolist(), dM=dM.tolist(), fro=fro, real_ratio=(real / real_gaz).tolist())
        print(f'  {n:5s} dg {np.round(dg[1:6],3)} | dM {np.round(dM,3)} | {fro:.3f} | {np.round(real/real_gaz,2)}')
    print('  GAZ real-data RMS err [Nm]', np.round(real_gaz, 3))

    grid = [  # (sigma_mass_log, sigma_com [m] or fraction of link size, sigma_inertia_log, com_rel?)
        (0.05, 0.005, 0.10, False), (0.10, 0.01, 0.20, False), (0.10, 0.01, 0.30, False),
        (0.15, 0.015, 0.30, False), (0.20, 0.02, 0.40, False), (0.30, 0.03, 0.50, False),
        (0.10, 0.0, 0.0, False), (0.0, 0.01, 0.0, False), (0.0, 0.0, 0.30, False),
        (0.10, 0.05, 0.30, True),
        (0.05, 0.005, 0.30, False), (0.05, 0.005, 0.50, False), (0.15, 0.015, 0.50, False), (0.10, 0.01, 0.50, False),
        (0.15, 0.015, 0.70, False),
        (0.15, 0.010, 0.30, False), (0.12, 0.012, 0.30, False), (0.10, 0.015, 0.30, False),
    ]
    ND = int(sys.argv[1]) if len(sys.argv) > 1 else 40
    res = []
    print(f'\nMonte Carlo ({ND} draws each): medians over draws [p90 in brackets for dg j2-4 mean]')
    for sm, sc, sI, rel in grid:
        rr = np.random.default_rng(7)
        D = [metrics(*perturb(mg, cg, Ig, sm, sc, sI, rr, LS if rel else None)) for _ in range(ND)]
        dg = np.array([d[0] for d in D]); dM = np.array([d[1] for d in D]); fro = np.array([d[2] for d in D])
        real = np.array([d[3] / real_gaz for d in D])
        lbl = f'sm={sm:.2f} sc={sc:.3f}{"xL" if rel else "m"} sI={sI:.2f}'
        print(f'  {lbl:34s} dg j2-6 {np.round(np.median(dg,0)[1:6],3)} [{np.percentile(dg[:,1:4].mean(1),90):.3f}]'
              f' | dM {np.round(np.median(dM,0),3)} | F {np.median(fro):.3f} | real {np.round(np.median(real,0),2)}')
        res.append(dict(sm=sm, sc=sc, sI=sI, com_rel=rel, dg_med=np.median(dg, 0).tolist(), dM_med=np.median(dM, 0).tolist(),
                        fro_med=float(np.median(fro)), real_ratio_med=np.median(real, 0).tolist(),
                        dg_p90=np.percentile(dg, 90, 0).tolist(), real_ratio_p90=np.percentile(real, 90, 0).tolist()))
    json.dump(dict(ref=out, grid=res, real_gaz=real_gaz.tolist()), open('mc_results.json', 'w'), indent=1)
