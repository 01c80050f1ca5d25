"""Plain-NumPy reference of the camera and image features (tests only; slow, explicit).

Written independently of ``vbl.vision``: the same documented definitions
(``docs/vision.md``) computed by different means -- the ball's outline is the projected
tangent circle of the sphere (sampled densely and refined by ternary search / bisection),
not its conic; segments are clipped by explicit loops; areas by explicit polygon
clipping (Sutherland-Hodgman) and the shoelace formula.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

# ----------------------------------------------------------------------------- camera


def _cam(cam) -> dict:
    if isinstance(cam, dict):
        d = dict(cam)
    else:
        d = {f.name: getattr(cam, f.name) for f in dataclasses.fields(cam)}
    out = dict(height=0.35, tilt_deg=-26.0, hfov_deg=67.0, vfov_deg=60.0, image_width=512,
               image_height=480, forward_offset=0.05, pixel_noise_std=0.0, near_plane=0.01)
    out.update({k: float(v) for k, v in d.items()})
    return out


def focal_np(cam) -> tuple[float, float]:
    c = _cam(cam)
    fu = (c["image_width"] / 2.0) / math.tan(math.radians(c["hfov_deg"]) / 2.0)
    fv = (c["image_height"] / 2.0) / math.tan(math.radians(c["vfov_deg"]) / 2.0)
    return fu, fv


def camera_axes_np(robot_pose, cam):
    """Camera centre and the right / up / forward unit vectors, built by rotations."""
    c = _cam(cam)
    x, y, th = (float(v) for v in robot_pose)
    tau = math.radians(c["tilt_deg"])
    centre = np.array([x + c["forward_offset"] * math.cos(th),
                       y + c["forward_offset"] * math.sin(th), c["height"]])
    # start from a camera looking along +x: forward (1,0,0), right (0,-1,0), up (0,0,1);
    # pitch by tau about the right axis, then yaw by theta about z.
    fwd0 = np.array([math.cos(tau), 0.0, math.sin(tau)])
    right0 = np.array([0.0, -1.0, 0.0])
    up0 = np.cross(right0, fwd0)
    yaw = np.array([[math.cos(th), -math.sin(th), 0.0], [math.sin(th), math.cos(th), 0.0],
                    [0.0, 0.0, 1.0]])
    return centre, yaw @ right0, yaw @ up0, yaw @ fwd0


def to_cam_np(p, robot_pose, cam):
    centre, right, up, fwd = camera_axes_np(robot_pose, cam)
    d = np.asarray(p, float) - centre
    return np.array([d @ right, d @ up, d @ fwd])


def project_points_np(points, robot_pose, cam):
    """(..., 3) world -> (uv (..., 2), depth (...)), one point at a time."""
    c = _cam(cam)
    fu, fv = focal_np(cam)
    pts = np.asarray(points, float)
    flat = pts.reshape(-1, 3)
    uv = np.zeros((flat.shape[0], 2))
    depth = np.zeros(flat.shape[0])
    for i, p in enumerate(flat):
        xc, yc, zc = to_cam_np(p, robot_pose, cam)
        zs = max(zc, c["near_plane"])
        uv[i] = [fu * xc / zs, fv * yc / zs]
        depth[i] = zc
    return uv.reshape(pts.shape[:-1] + (2,)), depth.reshape(pts.shape[:-1])


def _pix(pc, fu, fv):
    return np.array([fu * pc[0] / pc[2], fv * pc[1] / pc[2]])


# ----------------------------------------------------------------------------- ball


def _ray_hits_sphere(t, s, b, r):
    d = np.array([t, s, 1.0])
    along = b @ d / (d @ d)
    if along <= 0:
        return False
    return float(np.sum((b - along * d) ** 2)) <= r * r


def _outline(b, r, fu, fv):
    """Points (n, 2) px of the sphere's image outline: the projected tangent circle."""
    dist = np.linalg.norm(b)
    centre = b * (1.0 - r * r / dist**2)
    rho = r * math.sqrt(dist**2 - r * r) / dist
    axis = b / dist
    e1 = np.cross(axis, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)

    def at(phi):
        phi = np.asarray(phi, float)
        p = centre[:, None] * np.ones_like(phi) + rho * (np.cos(phi) * e1[:, None]
                                                        + np.sin(phi) * e2[:, None])
        return np.stack([fu * p[0] / p[2], fv * p[1] / p[2]], axis=-1)

    return at


def _ball_extent_1d(at, axis, lo_box, hi_box, hit, fu, fv, n=2000):
    """Extent along ``axis`` (0 = u, 1 = v) of the outline-enclosed region inside the box."""
    phis = np.linspace(0.0, 2 * math.pi, n, endpoint=False)
    pts = at(phis)
    cands = []
    inside = np.all((pts >= lo_box) & (pts <= hi_box), axis=1)
    # extreme outline points, refined by ternary search, if they are inside the box
    for sign in (-1.0, 1.0):
        i = int(np.argmin(sign * pts[:, axis]))
        a, b = phis[i] - 2 * math.pi / n, phis[i] + 2 * math.pi / n
        for _ in range(50):
            m1, m2 = a + (b - a) / 3, b - (b - a) / 3
            if sign * at([m1])[0, axis] < sign * at([m2])[0, axis]:
                b = m2
            else:
                a = m1
        p = at([0.5 * (a + b)])[0]
        if np.all(p >= lo_box) and np.all(p <= hi_box):
            cands.append(p[axis])
    # outline crossings of the box edges (sign changes between samples), refined by bisection
    nxt = np.roll(pts, -1, axis=0)
    for ax in (0, 1):
        for edge in (lo_box[ax], hi_box[ax]):
            fa_all, fb_all = pts[:, ax] - edge, nxt[:, ax] - edge
            for k in np.nonzero(fa_all * fb_all <= 0)[0]:
                fa = fa_all[k]
                if fa == 0 and fb_all[k] == 0:
                    continue
                a, b = phis[k], phis[k] + 2 * math.pi / n
                for _ in range(40):
                    m = 0.5 * (a + b)
                    if (at([m])[0, ax] - edge) * fa > 0:
                        a = m
                    else:
                        b = m
                p = at([0.5 * (a + b)])[0]
                p[ax] = edge
                o = 1 - ax
                if lo_box[o] - 1e-9 <= p[o] <= hi_box[o] + 1e-9:
                    cands.append(p[axis])
    # outline points inside (keeps the result robust when nothing crosses)
    if np.any(inside):
        cands.extend([pts[inside, axis].min(), pts[inside, axis].max()])
    # box corners covered by the ball
    for cu in (lo_box[0], hi_box[0]):
        for cv in (lo_box[1], hi_box[1]):
            if hit(cu / fu, cv / fv):
                cands.append((cu, cv)[axis])
    if not cands:
        return None
    return min(cands), max(cands)


def ball_box_np(b, r, cam):
    """Visible px box (u_lo, u_hi, v_lo, v_hi) of the ball with camera-frame centre b, or None."""
    c = _cam(cam)
    fu, fv = focal_np(cam)
    if b[2] - r < c["near_plane"]:
        return None
    at = _outline(b, r, fu, fv)
    lo_box = np.array([-c["image_width"] / 2, -c["image_height"] / 2])
    hi_box = -lo_box

    def hit(t, s):
        return _ray_hits_sphere(t, s, b, r)

    eu = _ball_extent_1d(at, 0, lo_box, hi_box, hit, fu, fv)
    ev = _ball_extent_1d(at, 1, lo_box, hi_box, hit, fu, fv)
    if eu is None or ev is None or eu[1] <= eu[0] or ev[1] <= ev[0]:
        return None
    return eu[0], eu[1], ev[0], ev[1]


def ball_column_chord_np(b, r, u, cam):
    """v-interval (px) of image column u covered by the ball, or None (ternary + bisection)."""
    fu, fv = focal_np(cam)
    t = u / fu

    def miss(s):  # distance of the ray from the centre minus r
        d = np.array([t, s, 1.0])
        along = b @ d / (d @ d)
        return math.sqrt(max(float(np.sum((b - along * d) ** 2)), 0.0)) - r

    a, z = -50.0, 50.0
    for _ in range(200):
        m1, m2 = a + (z - a) / 3, z - (z - a) / 3
        if miss(m1) < miss(m2):
            z = m2
        else:
            a = m1
    s0 = 0.5 * (a + z)
    if miss(s0) >= 0:
        return None
    ends = []
    for far in (-50.0, 50.0):
        a, z = s0, far
        for _ in range(100):
            m = 0.5 * (a + z)
            if miss(m) < 0:
                a = m
            else:
                z = m
        ends.append(fv * 0.5 * (a + z))
    return ends[0], ends[1]


# ----------------------------------------------------------------------------- segments


def _near_clip_np(a, b, zn):
    a, b = np.array(a, float), np.array(b, float)
    if a[2] < zn and b[2] < zn:
        return None
    if a[2] < zn:
        a = a + (zn - a[2]) / (b[2] - a[2]) * (b - a)
    if b[2] < zn:
        b = b + (zn - b[2]) / (a[2] - b[2]) * (a - b)
    return a, b


def _clip_segment_box(p, q, lo, hi):
    """Clip the 2-D segment p->q to the box by walking the four slabs one by one."""
    t_in, t_out = 0.0, 1.0
    for ax in (0, 1):
        d = q[ax] - p[ax]
        if abs(d) < 1e-12:
            if p[ax] < lo[ax] or p[ax] > hi[ax]:
                return None
            continue
        ta, tb = (lo[ax] - p[ax]) / d, (hi[ax] - p[ax]) / d
        if ta > tb:
            ta, tb = tb, ta
        t_in, t_out = max(t_in, ta), min(t_out, tb)
    if t_in > t_out:
        return None
    return p + t_in * (q - p), p + t_out * (q - p)


def goal_ends_np(pc, cam):
    """[(bottom (u,v), top (u,v)) or None] for the left and right goal ends."""
    c = _cam(cam)
    fu, fv = focal_np(cam)
    zn = c["near_plane"]
    hw, hh = c["image_width"] / 2, c["image_height"] / 2
    lo, hi = np.array([-hw, -hh]), np.array([hw, hh])

    def proj_seg(a, b):
        s = _near_clip_np(a, b, zn)
        return None if s is None else (_pix(s[0], fu, fv), _pix(s[1], fu, fv))

    bottom, top = proj_seg(pc[0], pc[3]), proj_seg(pc[1], pc[2])
    ends = []
    for post, col in (((pc[0], pc[1]), -hw), ((pc[3], pc[2]), hw)):
        seg = proj_seg(*post)
        clipped = None if seg is None else _clip_segment_box(seg[0], seg[1], lo, hi)
        if clipped is not None:
            p, q = clipped
            ends.append((p, q) if p[1] <= q[1] else (q, p))
            continue
        vs = []
        for e in (bottom, top):
            if e is None:
                break
            (u0, v0), (u1, v1) = e
            if abs(u1 - u0) <= 1e-6 or not (min(u0, u1) <= col <= max(u0, u1)):
                break
            vs.append(v0 + (col - u0) / (u1 - u0) * (v1 - v0))
        if len(vs) == 2:
            vlo = min(max(min(vs), -hh), hh)
            vhi = min(max(max(vs), -hh), hh)
            if vhi > vlo:
                ends.append((np.array([col, vlo]), np.array([col, vhi])))
                continue
        ends.append(None)
    return ends


def section2_features_np(robot_pose, ball_xy, ball_radius, goal_corners, cam):
    """Section 2 vector (9,) float64, by the definitions in docs/vision.md."""
    r = float(ball_radius)
    ball_w = np.array([ball_xy[0], ball_xy[1], r], float)
    b = to_cam_np(ball_w, robot_pose, cam)
    box = ball_box_np(b, r, cam)
    corners = np.asarray(goal_corners, float)
    pc = np.array([to_cam_np(p, robot_pose, cam) for p in corners])
    ends = goal_ends_np(pc, cam)
    out = np.zeros(9)
    if box is not None:
        out[0] = box[1] - box[0]
        out[1] = 0.5 * (box[0] + box[1])
        out[5] = 1.0
    else:
        out[7] = -1.0 if b[0] < 0 else 1.0
    goal_vis = any(e is not None and e[1][1] > e[0][1] for e in ends)
    if goal_vis:
        normal = np.cross(corners[1] - corners[0], corners[3] - corners[0])
        centre, *_ = camera_axes_np(robot_pose, cam)
        c = _cam(cam)
        ball_front = (((ball_w - corners[0]) @ normal) * ((centre - corners[0]) @ normal) > 0
                      and b[2] - r >= c["near_plane"])
        hs, us = [], []
        for e in ends:
            if e is None:
                hs.append(0.0)
                us.append(0.0)
                continue
            lo_pt, hi_pt = e
            u = 0.5 * (lo_pt[0] + hi_pt[0])
            vlo, vhi = lo_pt[1], hi_pt[1]
            chord = ball_column_chord_np(b, r, u, cam) if ball_front else None
            if chord is not None:
                olo, ohi = chord
                new_lo, new_hi = vlo, vhi
                if olo <= vlo < ohi:
                    new_lo = min(ohi, vhi)
                if olo < vhi <= ohi:
                    new_hi = max(olo, vlo)
                vlo, vhi = new_lo, max(new_hi, new_lo)
            hs.append(vhi - vlo)
            us.append(u)
        x3 = 0.5 * (hs[0] + hs[1])
        out[2] = x3
        out[3] = 0.5 * (us[0] + us[1])
        out[4] = min(max((hs[0] - hs[1]) / x3, -1.0), 1.0) if x3 > 0 else 0.0
        out[6] = 1.0
    else:
        out[8] = -1.0 if np.mean(pc[:, 0]) < 0 else 1.0
    return out


# ----------------------------------------------------------------------------- section 3


def _sh_clip(poly, inside, intersect):
    """One Sutherland-Hodgman pass."""
    out = []
    n = len(poly)
    for i in range(n):
        cur, nxt = poly[i], poly[(i + 1) % n]
        if inside(cur):
            out.append(cur)
            if not inside(nxt):
                out.append(intersect(cur, nxt))
        elif inside(nxt):
            out.append(intersect(cur, nxt))
    return out


def _clip_poly_box(poly, lo, hi):
    for ax in (0, 1):
        for bound, sign in ((lo[ax], 1.0), (hi[ax], -1.0)):
            def inside(p, ax=ax, bound=bound, sign=sign):
                return sign * (p[ax] - bound) >= 0

            def intersect(a, b, ax=ax, bound=bound):
                t = (bound - a[ax]) / (b[ax] - a[ax])
                return a + t * (b - a)

            poly = _sh_clip(poly, inside, intersect)
            if not poly:
                return []
    return poly


def _area_centroid(poly):
    """Unsigned area and centroid by the shoelace formula (sign-corrected)."""
    if len(poly) < 3:
        return 0.0, 0.0, 0.0
    a = cu = cv = 0.0
    for i in range(len(poly)):
        (x0, y0), (x1, y1) = poly[i], poly[(i + 1) % len(poly)]
        cr = x0 * y1 - x1 * y0
        a += cr / 2
        cu += (x0 + x1) * cr / 6
        cv += (y0 + y1) * cr / 6
    if a < 0:
        a, cu, cv = -a, -cu, -cv
    return a, cu, cv


def _image_polygon(pts_cam, cam):
    """Near-clip a 3-D polygon (camera coords) and project it to px (list of points)."""
    c = _cam(cam)
    fu, fv = focal_np(cam)
    zn = c["near_plane"]
    poly = [np.asarray(p, float) for p in pts_cam]
    poly = _sh_clip(poly, lambda p: p[2] >= zn,
                    lambda a, b: a + (zn - a[2]) / (b[2] - a[2]) * (b - a))
    return [_pix(p, fu, fv) for p in poly]


def _region(poly2d, boxes):
    """area, first moments (mu, mv), bbox of poly ∩ all boxes."""
    lo = np.max([b[0] for b in boxes], axis=0)
    hi = np.min([b[1] for b in boxes], axis=0)
    if np.any(hi <= lo):
        return 0.0, 0.0, 0.0, None
    clipped = _clip_poly_box(list(poly2d), lo, hi)
    a, mu, mv = _area_centroid(clipped)
    if a <= 0:
        return 0.0, 0.0, 0.0, None
    arr = np.array(clipped)
    return a, mu, mv, (arr.min(axis=0), arr.max(axis=0))


def _cut(lo, hi, olo, ohi):
    """Interval [lo, hi] minus an occluder that cuts off one end (or all of it)."""
    nlo, nhi = lo, hi
    if olo <= lo < ohi:
        nlo = min(ohi, hi)
    if olo < hi <= ohi:
        nhi = max(olo, lo)
    return nlo, max(nhi, nlo)


def _box_minus(box, occ):
    (lo, hi), (olo, ohi) = box, occ
    lo, hi = np.array(lo, float), np.array(hi, float)
    if not (np.all(ohi > lo) and np.all(olo < hi)):
        return lo, hi
    cov_u = olo[0] <= lo[0] and ohi[0] >= hi[0]
    cov_v = olo[1] <= lo[1] and ohi[1] >= hi[1]
    if cov_u and cov_v:
        return lo, lo.copy()
    nlo, nhi = lo.copy(), hi.copy()
    if cov_v:
        nlo[0], nhi[0] = _cut(lo[0], hi[0], olo[0], ohi[0])
    if cov_u:
        nlo[1], nhi[1] = _cut(lo[1], hi[1], olo[1], ohi[1])
    return nlo, nhi


def robot_box_corners_np(pose, size):
    x, y, th = (float(v) for v in pose)
    out = []
    for sz in (0.0, float(size[2])):
        for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1)):
            lx, ly = sx * size[0] / 2, sy * size[1] / 2
            out.append([x + math.cos(th) * lx - math.sin(th) * ly,
                        y + math.sin(th) * lx + math.cos(th) * ly, sz])
    return np.array(out)


def section3_features_np(robot_pose, ball_xy, ball_radius, goal_corners, other_pose,
                         other_size, cam):
    """Section 3 flat vector (26,) float64: ball 4, goal 11, other 5, visible 3, lost 3."""
    c = _cam(cam)
    hw, hh = c["image_width"] / 2, c["image_height"] / 2
    img = (np.array([-hw, -hh]), np.array([hw, hh]))
    centre, *_ = camera_axes_np(robot_pose, cam)
    r = float(ball_radius)
    ball_w = np.array([ball_xy[0], ball_xy[1], r], float)
    b = to_cam_np(ball_w, robot_pose, cam)
    bbox = ball_box_np(b, r, cam)
    ball_box = None if bbox is None else (np.array([bbox[0], bbox[2]]),
                                          np.array([bbox[1], bbox[3]]))
    corners = np.asarray(goal_corners, float)
    pc = np.array([to_cam_np(p, robot_pose, cam) for p in corners])
    ends = goal_ends_np(pc, cam)
    gpoly = _image_polygon(pc, cam)
    # other robot silhouette = its faces turned towards the camera
    bw = robot_box_corners_np(other_pose, other_size)
    ocen = bw.mean(axis=0)
    faces = [[0, 1, 2, 3], [4, 5, 6, 7], [0, 3, 7, 4], [1, 2, 6, 5], [0, 1, 5, 4],
             [3, 2, 6, 7]]
    face_polys = []
    for f in faces:
        fc = bw[f].mean(axis=0)
        if (fc - ocen) @ (centre - fc) > 0:
            face_polys.append(_image_polygon([to_cam_np(p, robot_pose, cam) for p in bw[f]],
                                             cam))

    def robot_region(boxes):
        a = mu = mv = 0.0
        los, his = [], []
        for poly in face_polys:
            fa, fmu, fmv, fb = _region(poly, boxes)
            if fb is not None:
                a, mu, mv = a + fa, mu + fmu, mv + fmv
                los.append(fb[0])
                his.append(fb[1])
        if not los:
            return 0.0, 0.0, 0.0, None
        return a, mu, mv, (np.min(los, axis=0), np.max(his, axis=0))

    o_full = robot_region([img])
    # depth order
    normal = np.cross(corners[1] - corners[0], corners[3] - corners[0])
    cam_side = (centre - corners[0]) @ normal
    ball_valid = b[2] - r >= c["near_plane"]
    ball_before_goal = ((ball_w - corners[0]) @ normal) * cam_side > 0 and ball_valid
    robot_before_goal = ((ocen - corners[0]) @ normal) * cam_side > 0
    th = float(other_pose[2])
    rot = np.array([[math.cos(th), math.sin(th), 0], [-math.sin(th), math.cos(th), 0],
                    [0, 0, 1]])
    half = np.array(other_size, float) / 2
    loc_b, loc_c = rot @ (ball_w - ocen), rot @ (centre - ocen)
    ax = int(np.argmax(np.abs(loc_b) / half))
    ball_before_robot = bool(np.sign(loc_b[ax]) * loc_c[ax] > half[ax]) and ball_valid
    # ball
    ball_f, ball_vis = np.zeros(4), False
    if ball_box is not None:
        lo, hi = ball_box
        if not ball_before_robot and o_full[3] is not None:
            lo, hi = _box_minus((lo, hi), o_full[3])
        if np.all(hi > lo):
            ball_vis = True
            ball_f = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, hi[0] - lo[0],
                               hi[1] - lo[1]])
    # other robot
    other_f, other_vis = np.zeros(5), False
    if o_full[3] is not None:
        a, mu, mv = o_full[:3]
        lo, hi = o_full[3]
        if ball_before_robot and ball_box is not None:
            oa, omu, omv, _ = robot_region([img, ball_box])
            a, mu, mv = a - oa, mu - omu, mv - omv
            lo, hi = _box_minus((lo, hi), ball_box)
        if a > 1e-6 and np.all(hi > lo):
            other_vis = True
            other_f = np.array([mu / a, mv / a, hi[0] - lo[0], hi[1] - lo[1], a])
    # goal
    goal_f, goal_vis = np.zeros(11), False
    occluders = []
    if ball_before_goal and ball_box is not None:
        occluders.append(ball_box)
    if robot_before_goal and o_full[3] is not None:
        occluders.append(o_full[3])
    a, mu, mv, _ = _region(gpoly, [img])
    for k, occ in enumerate(occluders):  # inclusion-exclusion over the occluder boxes
        oa, omu, omv, _ = _region(gpoly, [img, occ])
        a, mu, mv = a - oa, mu - omu, mv - omv
        for occ2 in occluders[k + 1:]:
            oa, omu, omv, _ = _region(gpoly, [img, occ, occ2])
            a, mu, mv = a + oa, mu + omu, mv + omv
    ends_vis = any(e is not None and e[1][1] > e[0][1] for e in ends)
    if ends_vis and a > 1e-6:
        goal_vis = True
        pts = []
        for e, which in ((ends[0], 0), (ends[0], 1), (ends[1], 1), (ends[1], 0)):
            pts.extend(e[which] if e is not None else (0.0, 0.0))
        goal_f = np.array(pts + [mu / a, mv / a, a])
    vis = [ball_vis, goal_vis, other_vis]
    refx = [b[0], pc.mean(axis=0)[0], to_cam_np(ocen, robot_pose, cam)[0]]
    lost = [0.0 if v else (-1.0 if x < 0 else 1.0) for v, x in zip(vis, refx, strict=True)]
    return np.concatenate([ball_f, goal_f, other_f, np.array(vis, float), lost])
