#!/usr/bin/env python3
"""Real frames: align the two NGI Baviaanskloof 2015 aerial frames of strip 05 (AGPL data,
read in place from ../shared/data, never copied) to renders of the 5 m orthophoto of the
same flight and of the 10 m Sentinel-2 image, both over the 24 m DEM, from priors 50 m and 3
degrees off the aero-triangulated pose, with the classical and the learned tracker; print
position and orientation errors against that pose, and for the converged answers their own
position sigma (root of the covariance's position trace) and NEES against that pose (6 where
the covariance is honest).

The exterior orientation (camera/ngi_xyz_opk.csv) is PATB: R_W_C = Rx(omega) Ry(phi)
Rz(kappa) for camera axes x right, y up, z back; ours look along +z with y down, so
R_W_C(ours) = R_PATB diag(1, -1, -1) (geo::pose_from_opk does the same).

usage: scripts/eval_baviaanskloof.py [--terralign BIN] [--shared DIR] [--priors N] [--seed S]
                                      [--weights FILE] [--json OUT] [--refine N]
                                      [--refine-uniform R]
Python standard library only."""
import argparse
import json
import math
import os
import random
import subprocess
import sys
import tempfile


def rot(axis, deg):
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    if axis == 'x':
        return [[1, 0, 0], [0, c, -s], [0, s, c]]
    if axis == 'y':
        return [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    return [[c, -s, 0], [s, c, 0], [0, 0, 1]]


def mul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def transpose(a):
    return [[a[j][i] for j in range(3)] for i in range(3)]


def quat(R):
    """(w, x, y, z) of a rotation matrix (Shepperd)."""
    t = R[0][0] + R[1][1] + R[2][2]
    if t > 0:
        s = math.sqrt(t + 1.0) * 2
        return (0.25 * s, (R[2][1] - R[1][2]) / s, (R[0][2] - R[2][0]) / s, (R[1][0] - R[0][1]) / s)
    i = max(range(3), key=lambda k: R[k][k])
    j, k = (i + 1) % 3, (i + 2) % 3
    s = math.sqrt(1.0 + R[i][i] - R[j][j] - R[k][k]) * 2
    q = [0.0] * 4
    q[0] = (R[k][j] - R[j][k]) / s
    q[1 + i] = 0.25 * s
    q[1 + j] = (R[j][i] + R[i][j]) / s
    q[1 + k] = (R[k][i] + R[i][k]) / s
    return tuple(q)


def matrix(q):
    w, x, y, z = q
    return [[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]]


def angle_deg(Ra, Rb):
    M = mul(transpose(Ra), Rb)
    c = max(-1.0, min(1.0, (M[0][0] + M[1][1] + M[2][2] - 1) / 2))
    return math.degrees(math.acos(c))


def rotation_vector(M):
    """angle x axis (rad) of a rotation matrix."""
    c = max(-1.0, min(1.0, (M[0][0] + M[1][1] + M[2][2] - 1) / 2))
    a = math.acos(c)
    v = [M[2][1] - M[1][2], M[0][2] - M[2][0], M[1][0] - M[0][1]]
    s = math.sqrt(sum(x * x for x in v))
    return [0.0, 0.0, 0.0] if s == 0 else [a * x / s for x in v]


def nees(cov, truth_t, truth_R, est_t, est_R):
    """e^T P^-1 e for e = (world-axis rotation truth * est^-1, truth - estimate), P the answer's
    covariance (align's order); None where P is singular."""
    e = rotation_vector(mul(truth_R, transpose(est_R))) + [truth_t[i] - est_t[i] for i in range(3)]
    A = [list(cov[r]) + [e[r]] for r in range(6)]  # solve P x = e by Gaussian elimination
    for c in range(6):
        piv = max(range(c, 6), key=lambda r: abs(A[r][c]))
        if A[piv][c] == 0:
            return None
        A[c], A[piv] = A[piv], A[c]
        for r in range(c + 1, 6):
            f = A[r][c] / A[c][c]
            A[r] = [A[r][k] - f * A[c][k] for k in range(7)]
    x = [0.0] * 6
    for r in range(5, -1, -1):
        x[r] = (A[r][6] - sum(A[r][k] * x[k] for k in range(r + 1, 6))) / A[r][r]
    return sum(e[i] * x[i] for i in range(6))


def axis_angle(axis, deg):
    n = math.sqrt(sum(v * v for v in axis))
    x, y, z = (v / n for v in axis)
    a = math.radians(deg)
    c, s, C = math.cos(a), math.sin(a), 1 - math.cos(a)
    return [[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
            [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
            [z * x * C - y * s, z * y * C + x * s, c + z * z * C]]


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--terralign', default=os.path.join(here, '..', 'build', 'release', 'tools', 'terralign', 'terralign'))
    ap.add_argument('--shared', default=os.environ.get('TERRALIGN_SHARED_DATA', os.path.join(here, '..', '..', 'shared', 'data')))
    ap.add_argument('--priors', type=int, default=8, help='priors per frame (default 8)')
    ap.add_argument('--seed', type=int, default=5)
    ap.add_argument('--json', help='write every result here')
    ap.add_argument('--weights', help="the learned tracker's weight file (default: the shipped one)")
    ap.add_argument('--refine', type=int, help="align's refinement passes (default: align's)")
    ap.add_argument('--refine-uniform', type=float,
                    help="align's --refine-uniform: passes without the M-estimator below this final residual")
    args = ap.parse_args()
    S = os.path.join(args.shared, 'ngi_baviaanskloof_2015')
    if not os.path.isdir(S):
        sys.exit(f'eval_baviaanskloof: {S} not found (the AGPL set is read in place from ../shared/data)')
    work = tempfile.mkdtemp(prefix='terralign_bav_')
    # ngi_int_param.yaml: f 120 mm, sensor 92.16 x 165.888 mm, 640 x 1152 px (0.144 mm), centred.
    cam = {"name": "NGI DMC frame, 640 x 1152", "width": 640, "height": 1152, "fx": 120 / 0.144, "fy": 120 / 0.144,
           "cx": 319.5, "cy": 575.5, "distortion": {"model": "none"}}
    with open(os.path.join(work, 'camera.json'), 'w') as f:
        json.dump(cam, f)
    frames = []
    with open(os.path.join(S, 'camera', 'ngi_xyz_opk.csv')) as f:
        next(f)
        for line in f:
            name, x, y, z, om, ph, ka = line.strip().split(',')
            if '_05_' not in name:
                continue
            R = mul(mul(mul(rot('x', float(om)), rot('y', float(ph))), rot('z', float(ka))), [[1, 0, 0], [0, -1, 0], [0, 0, -1]])
            frames.append((name, [float(x), float(y), float(z)], R))
    # The frame's own orthophoto (1 <-> 0182, 2 <-> 0184, PROVENANCE.md) and Sentinel-2.
    ortho_of = {'0182': 'ngi_rgb_byte_1.tif', '0184': 'ngi_rgb_byte_2.tif'}
    rng = random.Random(args.seed)
    results = []
    for name, t, R in frames:
        ortho = ortho_of[name.split('_')[4]]
        manifest = {"name": f"Baviaanskloof 2015 for {name}", "dem": {"file": os.path.join(S, 'dem', 'dem.tif')},
                    "layers": [{"name": "ortho_5m", "file": os.path.join(S, 'ortho', ortho)},
                               {"name": "sentinel2_10m", "file": os.path.join(S, 'satellite', 'sentinel2_b432_byte.tif')}]}
        mpath = os.path.join(work, f'map_{name}.json')
        with open(mpath, 'w') as f:
            json.dump(manifest, f)
        image = os.path.join(S, 'frames', name + '.tif')
        for k in range(args.priors):
            # 50 m in a random direction (horizontal and vertical) and 3 degrees about a random axis.
            d = [rng.gauss(0, 1) for _ in range(3)]
            n = math.sqrt(sum(v * v for v in d))
            tp = [t[i] + 50.0 * d[i] / n for i in range(3)]
            Rp = mul(axis_angle([rng.gauss(0, 1) for _ in range(3)], 3.0), R)
            q = quat(Rp)
            prior = ' '.join(f'{v:.6f}' for v in tp) + ' ' + ' '.join(f'{v:.9f}' for v in q)
            for layer in ('ortho_5m', 'sentinel2_10m'):
                for method in ('classic', 'nn'):
                    cmd = [args.terralign, 'align', '--map', mpath, '--camera', os.path.join(work, 'camera.json'),
                           '--image', image, '--prior', prior, '--layer', layer, '--method', method]
                    if method == 'nn' and args.weights:
                        cmd += ['--weights', args.weights]
                    if args.refine is not None:
                        cmd += ['--refine', str(args.refine)]
                    if args.refine_uniform is not None:
                        cmd += ['--refine-uniform', str(args.refine_uniform)]
                    p = subprocess.run(cmd, capture_output=True, text=True)
                    if p.returncode not in (0, 3):
                        sys.exit(f'eval_baviaanskloof: {" ".join(cmd)}: exit {p.returncode}: {p.stderr.strip()}')
                    out = json.loads(p.stdout)
                    pose = out['pose']
                    te = pose['position'] if isinstance(pose, dict) else pose[:3]
                    qe = pose['quaternion'] if isinstance(pose, dict) else pose[3:7]
                    pos_err = math.sqrt(sum((te[i] - t[i]) ** 2 for i in range(3)))
                    ang_err = angle_deg(matrix(qe), R)
                    # How far the answer's own covariance covers its error against the
                    # aero-triangulated pose (converged answers only: the others carry none).
                    cov = out.get('covariance') if out['converged'] else None
                    sigma_pos = math.sqrt(sum(cov[3 + i][3 + i] for i in range(3))) if cov else None
                    answer_nees = nees(cov, t, R, te, matrix(qe)) if cov else None
                    results.append({"frame": name, "prior": k, "layer": layer, "method": method,
                                    "converged": out['converged'], "reason": out['reason'],
                                    "position_error_m": pos_err, "angle_error_deg": ang_err, "position": te,
                                    "prior_position_error_m": 50.0, "prior_angle_error_deg": angle_deg(Rp, R),
                                    "sigma_position_m": sigma_pos, "nees": answer_nees,
                                    "residual_final": out.get('residual_final'), "refinements": out.get('refinements'),
                                    "uniform_refinements": out.get('uniform_refinements')})
                    print(f'{name} prior {k} {layer:14s} {method:7s} {pos_err:8.2f} m {ang_err:6.2f} deg  '
                          f'{"converged" if out["converged"] else out["reason"]}', flush=True)
    if args.json:
        with open(args.json, 'w') as f:
            json.dump(results, f, indent=1)

    def med(v):
        v = sorted(v)
        return v[len(v) // 2] if v else float('nan')

    # Spread: how far each answer lies from the median answer of its frame, reference and
    # method (the repeatability from different priors, apart from any common offset between
    # the aero-triangulated pose and the map).
    def spread(r):
        d = []
        for fr in {x['frame'] for x in r}:
            g = [x for x in r if x['frame'] == fr]
            m = [med([x['position'][i] for x in g]) for i in range(3)]
            d += [math.sqrt(sum((x['position'][i] - m[i]) ** 2 for i in range(3))) for x in g]
        return med(d)

    print('\n| reference | method | position error m (median / mean) | angle deg (median) | spread m (median) | < 10 m and < 0.5 deg | converged | converged and right | converged: position sigma m, NEES (medians) |')
    print('|---|---|---|---|---|---|---|---|---|')
    for layer in ('ortho_5m', 'sentinel2_10m'):
        for method in ('classic', 'nn'):
            r = [x for x in results if x['layer'] == layer and x['method'] == method]
            good = [x for x in r if x['position_error_m'] < 10 and x['angle_error_deg'] < 0.5]
            conv = [x for x in r if x['converged']]
            cg = [x for x in conv if x in good]
            print(f'| {layer} | {method} | {med([x["position_error_m"] for x in r]):.1f} / '
                  f'{sum(x["position_error_m"] for x in r) / len(r):.1f} | {med([x["angle_error_deg"] for x in r]):.2f} | '
                  f'{spread(r):.2f} | {100 * len(good) / len(r):.0f} % | {100 * len(conv) / len(r):.0f} % | '
                  f'{(100 * len(cg) / len(conv)) if conv else 0:.0f} % | '
                  f'{med([x["sigma_position_m"] for x in conv]):.2f}, {med([x["nees"] for x in conv if x["nees"] is not None]):.1f} |')
    print(f'\n{len(frames)} frames x {args.priors} priors (50 m, 3 deg), seed {args.seed}; prior angle error 3 deg')


if __name__ == '__main__':
    main()
