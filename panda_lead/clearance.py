"""Collision-aware IK: a classical way to keep the arm out of itself, batched in numpy.

The reference work's open question 3 asks whether a learned lead can keep the arm out of
itself; the fair classical rival is an IK that knows about self-collision. This is that rival:
the velocity-damper constraint of Faverjon & Tournassoud (1987), the one mink's
`CollisionAvoidanceLimit` imposes, on the IK's joint step dq:

    for every pair of arm capsules nearer than clearance + INFLUENCE:
        d_dot(dq) = n . (J_b(p_b) - J_a(p_a)) dq  >=  -gain * (d - clearance)

so a pair may close at most a fraction ``gain`` of its distance to the clearance per control
step, and a pair already inside the clearance is pushed apart. The IK's own step is then
replaced by the nearest step (least squares) that satisfies every such constraint, found by
Hildreth's dual coordinate ascent (exact for these few constraints after a few sweeps). With
no pair near, the step is the ordinary IK step, bit for bit.

Why not mink itself: it solves one QP per arm per step in Python (a `Configuration` per arm
and a QP solver), which would undo the batching; why not MuJoCo's distance sensors: they run
at every physics substep (five times per control step) for every pair. Here the arm's
collision geoms are capsules, whose distances are a closed form over all arms and pairs at
once, and the Jacobian of a point on a hinge chain is ``z_i x (p - anchor_i)`` per joint,
from MuJoCo's own joint axes and anchors. Its cost per control step is in docs/performance.md.
"""

from __future__ import annotations

import mujoco
import numpy as np

INFLUENCE = 0.05
"""Pairs farther than clearance + this (m) are not constrained."""
SLOTS = 3
"""Constraints per arm and step: its three nearest pairs (a fourth near pair waits a step)."""
SWEEPS = 10
"""Most Hildreth sweeps over the constraints (it stops at a sweep that changes nothing)."""


def capsule_pairs(model: mujoco.MjModel) -> np.ndarray:
    """(P, 2) geom ids of the arm's capsule pairs that MuJoCo's collision detection checks:
    collidable by contype/conaffinity, on different weld groups, not parent and child (unless
    the parent is the world), not excluded by a <contact><exclude>. The floor is not included."""
    m = model
    geoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] != 0 and
             (m.geom_contype[g] or m.geom_conaffinity[g])]
    if any(m.geom_type[g] != mujoco.mjtGeom.mjGEOM_CAPSULE for g in geoms):
        raise ValueError("collision-aware IK needs every arm collision geom to be a capsule")
    weld, parent = m.body_weldid, m.body_parentid
    filter_parent = not (m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT)
    excluded = set(int(s) for s in m.exclude_signature)
    pairs = []
    for i, g1 in enumerate(geoms):
        for g2 in geoms[i + 1:]:
            b1, b2 = sorted((int(m.geom_bodyid[g1]), int(m.geom_bodyid[g2])))
            w1, w2 = weld[b1], weld[b2]
            if not ((m.geom_contype[g1] & m.geom_conaffinity[g2]) or
                    (m.geom_contype[g2] & m.geom_conaffinity[g1])):
                continue
            if w1 == w2 or (b1 << 16) + b2 in excluded:
                continue
            if filter_parent and w1 and w2 and (w1 == weld[parent[w2]] or w2 == weld[parent[w1]]):
                continue
            pairs.append((g1, g2))
    return np.array(pairs, dtype=np.int64).reshape(-1, 2)


def segment_closest_points(p1, q1, p2, q2):
    """Closest points of segments p1-q1 and p2-q2, row by row ((M, 3) each; Ericson,
    Real-Time Collision Detection 5.1.9, for segments of non-zero length)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e = (d1 * d1).sum(-1), (d2 * d2).sum(-1)
    b, c, f = (d1 * d2).sum(-1), (d1 * r).sum(-1), (d2 * r).sum(-1)
    denom = a * e - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denom > 1e-12 * a * e, np.clip((b * f - c * e) / denom, 0.0, 1.0), 0.0)
    t = (b * s + f) / e
    s = np.where(t < 0, np.clip(-c / a, 0.0, 1.0), np.where(t > 1, np.clip((b - c) / a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    return p1 + d1 * s[:, None], p2 + d2 * t[:, None]


class Clearance:
    """The constraint above for N arms of one model; ``project(dq)`` is called by the IK."""

    def __init__(self, model: mujoco.MjModel, batch, n_joints: int, clearance: float,
                 gain: float = 0.5):
        if clearance <= 0 or not 0 < gain <= 1:
            raise ValueError(f"clearance must be > 0 and 0 < gain <= 1, got {clearance}, {gain}")
        self.clearance, self.gain = float(clearance), float(gain)
        self.pairs = capsule_pairs(model)
        g1, g2 = self.pairs.T
        self._radius = model.geom_size[:, 0]
        self._half = model.geom_size[:, 1]
        self._bodies = model.geom_bodyid[self.pairs]  # (P, 2)
        # Bounding spheres: a pair is no nearer than its centres' distance less this.
        self._bound = (self._half + self._radius)[g1] + (self._half + self._radius)[g2]
        # moves[b, i]: joint i turns body b (joint i's body is b or one of b's ancestors).
        moves = np.zeros((model.nbody, n_joints), dtype=bool)
        for body in range(model.nbody):
            for i in range(n_joints):
                a = body
                while a and a != model.jnt_bodyid[i]:
                    a = model.body_parentid[a]
                moves[body, i] = a == model.jnt_bodyid[i]
        self._moves = moves
        # Live views of the kinematics (bound outputs: refreshed by every batch call).
        self._geom_pos = batch.bind("geom_xpos")
        self._geom_mat = batch.bind("geom_xmat")
        self._axis = batch.bind("xaxis")[:, :n_joints]
        self._anchor = batch.bind("xanchor")[:, :n_joints]

    def distances(self):
        """Surface distance (m), unit normal from the first capsule to the second, and the
        two surface points, for every arm and pair: (N, P), (N, P, 3), (N, P, 3), (N, P, 3)."""
        dist, c1, c2 = self._closest()
        return (dist, *self._surface(c1, c2, self.pairs))

    def _closest(self, within: float = np.inf):
        """Surface distances (N, P) and the closest points of the capsules' segments (N, P, 3).
        Pairs whose bounding spheres are farther apart than ``within`` are skipped: their
        distance is reported as infinite and their points as zero."""
        n, (g1, g2) = self._geom_pos.shape[0], self.pairs.T
        centre1, centre2 = self._geom_pos[:, g1], self._geom_pos[:, g2]
        dist = np.full((n, len(self.pairs)), np.inf)
        c1, c2 = np.zeros((2, n, len(self.pairs), 3))
        check = (np.linalg.norm(centre2 - centre1, axis=-1) - self._bound) < within
        i, k = np.nonzero(check)
        if i.size:
            mats = self._geom_mat.reshape(n, -1, 3, 3)
            half1 = mats[i, g1[k], :, 2] * self._half[g1[k], None]  # each capsule's local z
            half2 = mats[i, g2[k], :, 2] * self._half[g2[k], None]
            a, b = centre1[i, k], centre2[i, k]
            p, q = segment_closest_points(a - half1, a + half1, b - half2, b + half2)
            c1[i, k], c2[i, k] = p, q
            dist[i, k] = np.linalg.norm(q - p, axis=-1) - self._radius[g1[k]] - self._radius[g2[k]]
        return dist, c1, c2

    def _surface(self, c1, c2, pairs):
        """Unit normals and surface points from segment points c1, c2 of capsule pairs."""
        delta = c2 - c1
        normal = delta / np.maximum(np.linalg.norm(delta, axis=-1), 1e-12)[..., None]
        r1, r2 = self._radius[pairs[..., 0]], self._radius[pairs[..., 1]]
        return normal, c1 + r1[..., None] * normal, c2 - r2[..., None] * normal

    def project(self, dq: np.ndarray) -> np.ndarray:
        """The step nearest dq (least squares) that meets every near pair's constraint."""
        dist, c1, c2 = self._closest(within=self.clearance + INFLUENCE)
        k = min(SLOTS, dist.shape[1])
        nearest = np.argpartition(dist, k - 1, axis=1)[:, :k]  # (N, k) pair indices
        d = np.take_along_axis(dist, nearest, 1)
        near = d < self.clearance + INFLUENCE
        rows = np.nonzero(near.any(axis=1))[0]
        if rows.size == 0:
            return dq
        pick = nearest[rows]
        take = lambda x: np.take_along_axis(x[rows], pick[..., None], 1)  # noqa: E731
        n_, a1, a2 = self._surface(take(c1), take(c2), self.pairs[pick])  # (R, k, 3)
        body1, body2 = self._bodies[pick, 0], self._bodies[pick, 1]  # (R, k)
        z, anchor = self._axis[rows][:, None], self._anchor[rows][:, None]  # (R, 1, J, 3)
        # d_dot per joint: n . (z_i x (p2 - anchor_i)) [i moves body2] - same for p1, body1.
        v2 = np.cross(z, a2[:, :, None] - anchor) * self._moves[body2][..., None]
        v1 = np.cross(z, a1[:, :, None] - anchor) * self._moves[body1][..., None]
        a = np.einsum("rkjc,rkc->rkj", v2 - v1, n_)  # (R, k, J)
        b = np.where(near[rows], -self.gain * (d[rows] - self.clearance), -np.inf)
        x = dq[rows].copy()
        lam = np.zeros(b.shape)
        norm2 = np.maximum(np.einsum("rkj,rkj->rk", a, a), 1e-12)
        for _ in range(SWEEPS):
            moved = 0.0
            for j in range(k):
                step = (b[:, j] - np.einsum("rj,rj->r", a[:, j], x)) / norm2[:, j]
                step = np.maximum(step, -lam[:, j])  # the multiplier stays >= 0
                lam[:, j] += step
                x += step[:, None] * a[:, j]
                moved = max(moved, float(np.abs(step).max()))
            if moved < 1e-12:  # converged: a sweep that changes nothing
                break
        out = dq.copy()
        out[rows] = x
        return out
