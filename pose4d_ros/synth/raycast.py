"""Numba ray-casting kernels of the synthetic RGB-D renderer.

Rays leave the camera centre through pixel centres, `d = ((u - cx) / fx, (v - cy) / fy, 1)` in
the optical frame (x right, y down, z forward, metres), so the ray parameter along `d` is the
depth z that a depth camera reports. Primitives:

- oriented boxes (the room: floor, walls, furniture), intersected by the slab method in the
  box's own frame; rendered once per scene for every pixel;
- capsules (limbs) and ellipsoids (head, hair, torso, pelvis) of the body, intersected
  analytically (the capsule after I. Quilez's closed form), each inside the screen box of its
  bounding sphere, against a depth buffer holding the room, so that occluded body pixels are
  never written.

Texture coordinates (s, t) are metres on the surface: for a box face, along its two other axes
(t grows downwards on vertical faces, so photographs hang upright); for a capsule, s around the
axis (angle times radius) and t along it; for an ellipsoid, s around its vertical axis and t
down it. Tiles are sampled bilinearly with mirrored repetition (no seams).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

_EPS = 1e-9


@njit(cache=True, inline='always')
def _mirror(i: int, n: int) -> int:
    i = i % (2 * n)
    if i < 0:
        i += 2 * n
    if i >= n:
        i = 2 * n - 1 - i
    return i


@njit(cache=True)
def sample_tile(tiles: NDArray[np.float32], scale: NDArray[np.float32], m: int, s: float,
                t: float, out: NDArray[np.float64]) -> None:
    """Bilinear, mirrored-repeat sample of material m at (s, t) metres into out[0:3]."""
    n = tiles.shape[1]
    x = s / scale[m, 0] * n - 0.5
    y = t / scale[m, 1] * n - 0.5
    x0 = math.floor(x)
    y0 = math.floor(y)
    fx = x - x0
    fy = y - y0
    xa = _mirror(int(x0), n)
    xb = _mirror(int(x0) + 1, n)
    ya = _mirror(int(y0), n)
    yb = _mirror(int(y0) + 1, n)
    for c in range(3):
        top = tiles[m, ya, xa, c] * (1.0 - fx) + tiles[m, ya, xb, c] * fx
        bot = tiles[m, yb, xa, c] * (1.0 - fx) + tiles[m, yb, xb, c] * fx
        out[c] = top * (1.0 - fy) + bot * fy


@njit(cache=True)
def raycast_boxes(fx: float, fy: float, cx: float, cy: float, height: int, width: int,
                  centers: NDArray[np.float64], rots: NDArray[np.float64],
                  halves: NDArray[np.float64], mats: NDArray[np.int64],
                  tiles: NDArray[np.float32], scale: NDArray[np.float32],
                  depth: NDArray[np.float32], normal: NDArray[np.float32],
                  albedo: NDArray[np.float32], ids: NDArray[np.int32]) -> None:
    """Render oriented boxes for every pixel (the room, once per scene).

    Parameters
    ----------
    centers : (N, 3) float64 box centres, optical frame, metres.
    rots : (N, 3, 3) float64; row k = the box's local axis k in the optical frame.
    halves : (N, 3) float64 half sizes along the local axes, metres.
    mats : (N,) int64 material index.
    tiles, scale : materials (see textures.Materials).
    depth : (H, W) float32 out, z metres (inf = nothing hit).
    normal : (H, W, 3) float32 out, unit normal facing the camera.
    albedo : (H, W, 3) float32 out.
    ids : (H, W) int32 out, box index (-1 = nothing).
    """
    n = centers.shape[0]
    ol = np.empty((n, 3))
    for b in range(n):
        for k in range(3):
            ol[b, k] = -(rots[b, k, 0] * centers[b, 0] + rots[b, k, 1] * centers[b, 1]
                         + rots[b, k, 2] * centers[b, 2])
    dl = np.empty(3)
    col = np.empty(3)
    for v in range(height):
        for u in range(width):
            dx = (u - cx) / fx
            dy = (v - cy) / fy
            best = np.inf
            bbox = -1
            baxis = 0
            bsign = 1.0
            for b in range(n):
                for k in range(3):
                    dl[k] = rots[b, k, 0] * dx + rots[b, k, 1] * dy + rots[b, k, 2]
                tmin = -np.inf
                tmax = np.inf
                axis = 0
                sign = 1.0
                miss = False
                for k in range(3):
                    if abs(dl[k]) < _EPS:
                        if abs(ol[b, k]) > halves[b, k]:
                            miss = True
                            break
                        continue
                    t1 = (-halves[b, k] - ol[b, k]) / dl[k]
                    t2 = (halves[b, k] - ol[b, k]) / dl[k]
                    sg = -1.0
                    if t1 > t2:
                        t1, t2 = t2, t1
                        sg = 1.0
                    if t1 > tmin:
                        tmin = t1
                        axis = k
                        sign = sg
                    if t2 < tmax:
                        tmax = t2
                if miss or tmax < tmin or tmin <= 0.0:
                    continue  # the camera is never inside a box
                if tmin < best:
                    best = tmin
                    bbox = b
                    baxis = axis
                    bsign = sign
            ids[v, u] = bbox
            if bbox < 0:
                depth[v, u] = np.inf
                for c in range(3):
                    normal[v, u, c] = 0.0
                    albedo[v, u, c] = 0.0
                continue
            depth[v, u] = best
            for c in range(3):
                normal[v, u, c] = bsign * rots[bbox, baxis, c]
            # local hit point -> face texture coordinates (metres from the face's corner)
            p = np.empty(3)
            for k in range(3):
                p[k] = ol[bbox, k] + best * (rots[bbox, k, 0] * dx + rots[bbox, k, 1] * dy
                                             + rots[bbox, k, 2])
            j = (baxis + 1) % 3
            k2 = (baxis + 2) % 3
            if j > k2:
                j, k2 = k2, j
            s = p[j] + halves[bbox, j]
            t = halves[bbox, k2] - p[k2]
            sample_tile(tiles, scale, mats[bbox], s, t, col)
            for c in range(3):
                albedo[v, u, c] = col[c]


@njit(cache=True)
def _sphere_box(cx3: float, cy3: float, cz3: float, rad: float, fx: float, fy: float,
                cx: float, cy: float, width: int, height: int) -> tuple[int, int, int, int]:
    """Conservative pixel box (u0, u1, v0, v1) of a sphere; empty when behind the camera."""
    if cz3 + rad <= 0.05:
        return 0, -1, 0, -1
    if cz3 - rad <= 0.05:
        return 0, width - 1, 0, height - 1
    za = cz3 - rad
    zb = cz3 + rad
    umin = cx + fx * min((cx3 - rad) / za, (cx3 - rad) / zb)
    umax = cx + fx * max((cx3 + rad) / za, (cx3 + rad) / zb)
    vmin = cy + fy * min((cy3 - rad) / za, (cy3 - rad) / zb)
    vmax = cy + fy * max((cy3 + rad) / za, (cy3 + rad) / zb)
    u0 = max(int(math.floor(umin)), 0)
    u1 = min(int(math.ceil(umax)), width - 1)
    v0 = max(int(math.floor(vmin)), 0)
    v1 = min(int(math.ceil(vmax)), height - 1)
    return u0, u1, v0, v1


@njit(cache=True)
def raycast_body(fx: float, fy: float, cx: float, cy: float, zbuf: NDArray[np.float32],
                 cap_a: NDArray[np.float64], cap_b: NDArray[np.float64],
                 cap_r: NDArray[np.float64], cap_e1: NDArray[np.float64],
                 ell_c: NDArray[np.float64], ell_rot: NDArray[np.float64],
                 ell_r: NDArray[np.float64], ids: NDArray[np.int32],
                 normal: NDArray[np.float32], st: NDArray[np.float32]) -> None:
    """Ray-cast the body's capsules and ellipsoids into a depth buffer. (One numba kernel of
    more than 100 lines: split into calls, its per-pixel loop would pay for them.)

    Parameters
    ----------
    zbuf : (H, W) float32 in/out: the room's depth on entry (inf = nothing), the nearest
        surface's z on exit.
    cap_a, cap_b : (Nc, 3) float64 capsule end points, optical frame, metres.
    cap_r : (Nc,) float64 radii.
    cap_e1 : (Nc, 3) float64 unit vectors perpendicular to each axis (s = 0 direction).
    ell_c : (Ne, 3) float64 centres; ell_rot : (Ne, 3, 3) rows = local axes (x, y = "down the
        body", z); ell_r : (Ne, 3) semi-axes.
    ids : (H, W) int32 out (fill with -1 first): primitive index, capsules first.
    normal : (H, W, 3) float32 out; st : (H, W, 2) float32 out, texture coordinates.
    """
    height, width = zbuf.shape
    nc = cap_a.shape[0]
    ne = ell_c.shape[0]
    for i in range(nc):
        ax, ay, az = cap_a[i, 0], cap_a[i, 1], cap_a[i, 2]
        bax, bay, baz = cap_b[i, 0] - ax, cap_b[i, 1] - ay, cap_b[i, 2] - az
        r = cap_r[i]
        baba = bax * bax + bay * bay + baz * baz
        blen = math.sqrt(baba)
        if blen < 1e-9:
            continue
        u0, u1, v0, v1 = _sphere_box(ax + 0.5 * bax, ay + 0.5 * bay, az + 0.5 * baz,
                                     0.5 * blen + r, fx, fy, cx, cy, width, height)
        # e2 = axis x e1 completes the frame for the angle around the axis
        e1x, e1y, e1z = cap_e1[i, 0], cap_e1[i, 1], cap_e1[i, 2]
        wx, wy, wz = bax / blen, bay / blen, baz / blen
        e2x = wy * e1z - wz * e1y
        e2y = wz * e1x - wx * e1z
        e2z = wx * e1y - wy * e1x
        oax, oay, oaz = -ax, -ay, -az
        baoa = bax * oax + bay * oay + baz * oaz
        oaoa = oax * oax + oay * oay + oaz * oaz
        for v in range(v0, v1 + 1):
            for u in range(u0, u1 + 1):
                dx = (u - cx) / fx
                dy = (v - cy) / fy
                inv = 1.0 / math.sqrt(dx * dx + dy * dy + 1.0)
                rdx, rdy, rdz = dx * inv, dy * inv, inv
                bard = bax * rdx + bay * rdy + baz * rdz
                rdoa = rdx * oax + rdy * oay + rdz * oaz
                a = baba - bard * bard
                b = baba * rdoa - baoa * bard
                c = baba * oaoa - baoa * baoa - r * r * baba
                h = b * b - a * c
                t = -1.0
                if h >= 0.0 and a > 1e-12:
                    t = (-b - math.sqrt(h)) / a
                    y = baoa + t * bard
                    if not (0.0 < y < baba):
                        # the end caps: spheres at a or b
                        if y <= 0.0:
                            ocx, ocy, ocz = oax, oay, oaz
                        else:
                            ocx, ocy, ocz = -cap_b[i, 0], -cap_b[i, 1], -cap_b[i, 2]
                        b2 = rdx * ocx + rdy * ocy + rdz * ocz
                        c2 = ocx * ocx + ocy * ocy + ocz * ocz - r * r
                        h2 = b2 * b2 - c2
                        t = -b2 - math.sqrt(h2) if h2 > 0.0 else -1.0
                if t <= 0.0:
                    continue
                z = t * rdz
                if z >= zbuf[v, u]:
                    continue
                px, py, pz = t * rdx, t * rdy, t * rdz
                q = ((px - ax) * bax + (py - ay) * bay + (pz - az) * baz) / baba
                q = min(max(q, 0.0), 1.0)
                nx = (px - ax - q * bax) / r
                ny = (py - ay - q * bay) / r
                nz = (pz - az - q * baz) / r
                zbuf[v, u] = z
                ids[v, u] = i
                normal[v, u, 0] = nx
                normal[v, u, 1] = ny
                normal[v, u, 2] = nz
                ang = math.atan2(nx * e2x + ny * e2y + nz * e2z, nx * e1x + ny * e1y + nz * e1z)
                st[v, u, 0] = (ang + math.pi) * r
                st[v, u, 1] = q * blen
    for i in range(ne):
        rx, ry, rz = ell_r[i, 0], ell_r[i, 1], ell_r[i, 2]
        u0, u1, v0, v1 = _sphere_box(ell_c[i, 0], ell_c[i, 1], ell_c[i, 2], max(rx, ry, rz),
                                     fx, fy, cx, cy, width, height)
        # camera origin in the unit-sphere frame
        ox = -(ell_rot[i, 0, 0] * ell_c[i, 0] + ell_rot[i, 0, 1] * ell_c[i, 1]
               + ell_rot[i, 0, 2] * ell_c[i, 2]) / rx
        oy = -(ell_rot[i, 1, 0] * ell_c[i, 0] + ell_rot[i, 1, 1] * ell_c[i, 1]
               + ell_rot[i, 1, 2] * ell_c[i, 2]) / ry
        oz = -(ell_rot[i, 2, 0] * ell_c[i, 0] + ell_rot[i, 2, 1] * ell_c[i, 1]
               + ell_rot[i, 2, 2] * ell_c[i, 2]) / rz
        oo = ox * ox + oy * oy + oz * oz
        for v in range(v0, v1 + 1):
            for u in range(u0, u1 + 1):
                dx = (u - cx) / fx
                dy = (v - cy) / fy
                lx = (ell_rot[i, 0, 0] * dx + ell_rot[i, 0, 1] * dy + ell_rot[i, 0, 2]) / rx
                ly = (ell_rot[i, 1, 0] * dx + ell_rot[i, 1, 1] * dy + ell_rot[i, 1, 2]) / ry
                lz = (ell_rot[i, 2, 0] * dx + ell_rot[i, 2, 1] * dy + ell_rot[i, 2, 2]) / rz
                a = lx * lx + ly * ly + lz * lz
                b = ox * lx + oy * ly + oz * lz
                c = oo - 1.0
                h = b * b - a * c
                if h < 0.0:
                    continue
                t = (-b - math.sqrt(h)) / a  # along d, whose z is 1: t is the depth
                if t <= 0.0 or t >= zbuf[v, u]:
                    continue
                qx, qy, qz = ox + t * lx, oy + t * ly, oz + t * lz  # on the unit sphere
                gx, gy, gz = qx / rx, qy / ry, qz / rz  # gradient in the local frame
                nx = ell_rot[i, 0, 0] * gx + ell_rot[i, 1, 0] * gy + ell_rot[i, 2, 0] * gz
                ny = ell_rot[i, 0, 1] * gx + ell_rot[i, 1, 1] * gy + ell_rot[i, 2, 1] * gz
                nz = ell_rot[i, 0, 2] * gx + ell_rot[i, 1, 2] * gy + ell_rot[i, 2, 2] * gz
                nn = 1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
                zbuf[v, u] = t
                ids[v, u] = nc + i
                normal[v, u, 0] = nx * nn
                normal[v, u, 1] = ny * nn
                normal[v, u, 2] = nz * nn
                st[v, u, 0] = (math.atan2(qx, qz) + math.pi) * rx
                st[v, u, 1] = (qy + 1.0) * ry


@njit(cache=True)
def shade(bg_albedo: NDArray[np.float32], bg_normal: NDArray[np.float32],
          bg_ids: NDArray[np.int32], depth: NDArray[np.float32], body_ids: NDArray[np.int32],
          body_normal: NDArray[np.float32], body_st: NDArray[np.float32],
          prim_mat: NDArray[np.int64], tiles: NDArray[np.float32], scale: NDArray[np.float32],
          light: NDArray[np.float64], ambient: float, diffuse: float,
          colour: NDArray[np.float64], floor_id: int, blobs: NDArray[np.float64], fx: float,
          fy: float, cx: float, cy: float, out: NDArray[np.float32]) -> None:
    """Lambertian + ambient shading of the composed room and body, into out (H, W, 3) float32.

    light : (3,) unit vector towards the light, optical frame. colour : (3,) light colour.
    blobs : (B, 5) contact shadows on the floor: centre (optical, metres), radius and strength
    (0-1); floor pixels near them darken (ambient occlusion under the feet and body).
    """
    height, width = depth.shape
    col = np.empty(3)
    for v in range(height):
        for u in range(width):
            k = body_ids[v, u]
            if k >= 0:
                sample_tile(tiles, scale, prim_mat[k], body_st[v, u, 0], body_st[v, u, 1], col)
                nx, ny, nz = body_normal[v, u, 0], body_normal[v, u, 1], body_normal[v, u, 2]
            else:
                if bg_ids[v, u] < 0:
                    for c in range(3):
                        out[v, u, c] = 0.0
                    continue
                for c in range(3):
                    col[c] = bg_albedo[v, u, c]
                nx, ny, nz = bg_normal[v, u, 0], bg_normal[v, u, 1], bg_normal[v, u, 2]
            lam = nx * light[0] + ny * light[1] + nz * light[2]
            if lam < 0.0:
                lam = 0.0
            occl = 1.0
            if k < 0 and bg_ids[v, u] == floor_id:
                z = depth[v, u]
                px, py = (u - cx) / fx * z, (v - cy) / fy * z
                for j in range(blobs.shape[0]):
                    ddx, ddy, ddz = px - blobs[j, 0], py - blobs[j, 1], z - blobs[j, 2]
                    d2 = (ddx * ddx + ddy * ddy + ddz * ddz) / (blobs[j, 3] * blobs[j, 3])
                    if d2 < 9.0:
                        occl *= 1.0 - blobs[j, 4] * math.exp(-d2)
            g = (ambient + diffuse * lam) * occl
            for c in range(3):
                out[v, u, c] = col[c] * g * colour[c]


@njit(cache=True)
def projector_shadow(depth: NDArray[np.float32], fb: float) -> NDArray[np.bool_]:
    """Pixels the Kinect's infrared projector cannot see (no reading), per image row.

    The projector sits a baseline b beside the camera, so a point at depth z appears in the
    projector's view at u_p = u - f b / z. Scanning each row from the right, a pixel whose u_p
    falls behind (right of) the leftmost u_p seen so far is hidden from the projector by a
    nearer surface: this leaves a band of no reading beside the left of foreground edges,
    f b (1/z_near - 1/z_far) pixels wide.

    Parameters
    ----------
    depth : (H, W) float32 metres, inf/NaN = nothing.
    fb : focal length (px) times baseline (m).

    Returns
    -------
    (H, W) bool, True = in the projector's shadow.
    """
    height, width = depth.shape
    out = np.zeros((height, width), dtype=np.bool_)
    for v in range(height):
        running = np.inf
        for u in range(width - 1, -1, -1):
            z = depth[v, u]
            if not (z > 0.0 and z < 1e6):
                continue
            up = u - fb / z
            if up > running + 0.25:
                out[v, u] = True
            elif up < running:
                running = up
    return out
