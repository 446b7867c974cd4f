"""Minimal RNEA for the Panda arm (links 1..7, URDF joint origins, no hand)."""
import re
import numpy as np
from sets import tensor

G0 = 9.80665
PI = np.pi
JOINTS = [  # (xyz, rpy) of joint i in frame i-1 (franka_description panda URDF)
    ((0, 0, 0.333), (0, 0, 0)),
    ((0, 0, 0), (-PI / 2, 0, 0)),
    ((0, -0.316, 0), (PI / 2, 0, 0)),
    ((0.0825, 0, 0), (PI / 2, 0, 0)),
    ((-0.0825, 0.384, 0), (-PI / 2, 0, 0)),
    ((0, 0, 0), (PI / 2, 0, 0)),
    ((0.088, 0, 0), (PI / 2, 0, 0)),
]
QMIN = np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
QMAX = np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])


def rotx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rotz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


R0 = [rotx(rpy[0]) for _, rpy in JOINTS]   # only roll used in the Panda URDF
P = [np.array(xyz, float) for xyz, _ in JOINTS]
Z = np.array([0.0, 0.0, 1.0])


class Model:
    def __init__(self, pset):
        self.m = pset['m']
        self.c = pset['c']
        self.I = [tensor(r) for r in pset['I']]

    def rnea(self, q, qd, qdd, g=G0):
        n = 7
        R = [R0[i] @ rotz(q[i]) for i in range(n)]
        w = np.zeros(3); wd = np.zeros(3); a = np.array([0, 0, g], float)
        F = []; N = []
        for i in range(n):
            Rt = R[i].T
            a = Rt @ (a + np.cross(wd, P[i]) + np.cross(w, np.cross(w, P[i])))
            w_new = Rt @ w + qd[i] * Z
            wd = Rt @ wd + np.cross(Rt @ w, qd[i] * Z) + qdd[i] * Z
            w = w_new
            ac = a + np.cross(wd, self.c[i]) + np.cross(w, np.cross(w, self.c[i]))
            F.append(self.m[i] * ac)
            N.append(self.I[i] @ wd + np.cross(w, self.I[i] @ w))
        tau = np.zeros(n)
        f = np.zeros(3); nn = np.zeros(3)
        for i in reversed(range(n)):
            if i < n - 1:
                fc = R[i + 1] @ f
                nn = N[i] + R[i + 1] @ nn + np.cross(self.c[i], F[i]) + np.cross(P[i + 1], fc)
                f = fc + F[i]
            else:
                nn = N[i] + np.cross(self.c[i], F[i])
                f = F[i]
            tau[i] = nn[2]
        return tau

    def gravity(self, q):
        return self.rnea(q, np.zeros(7), np.zeros(7))

    def mass_matrix(self, q):
        M = np.zeros((7, 7))
        for j in range(7):
            e = np.zeros(7); e[j] = 1
            M[:, j] = self.rnea(q, np.zeros(7), e, g=0.0)
        return M


def load_matlab_fn(path, fname):
    """Translate a Symbolic-Toolbox generated MATLAB function into a python callable."""
    src = open(path).read()
    head = re.search(r"function\s+(\w+)\s*=\s*%s\(([^)]*)\)" % fname, src)
    out, args = head.group(1), [a.strip() for a in head.group(2).split(',')]
    body = src[head.end():]
    lines = [l.split('%')[0].strip() for l in body.splitlines()]
    code = ' '.join(l for l in lines if l)
    code = code.replace('.^', '**').replace('.*', '*').replace('./', '/')
    stmts = [s.strip() for s in code.split(';') if s.strip()]
    # rebuild: statements are "name = expr" except inside the final [..;..] vector
    text = ';'.join(stmts)
    m = re.search(r"%s\s*=\s*\[(.*)\]" % out, text)
    vec = m.group(1).split(';')
    pre = text[:m.start()].split(';')
    def fn(*vals, **kw):
        env = dict(zip(args, vals)); env.update(kw)
        env.update(cos=np.cos, sin=np.sin, exp=np.exp, sqrt=np.sqrt)
        for s in pre:
            if '=' in s:
                k, v = s.split('=', 1)
                env[k.strip()] = eval(v, {}, env)
        return np.array([eval(e, {}, env) for e in vec], float)
    return fn, args
