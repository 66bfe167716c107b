#!/usr/bin/env python3
"""Cross-date pairs from Bavaria: `terralign eval` on the three OrthoLoC web samples that come
with both orthophotos of one 1024 x 1024 window (CC BY-NC-SA 4.0: read in place from
../shared/data, never copied; evaluation only). The map is the official state DOP (`xdop`,
another date, summer, buildings leaning as a survey's do, a burnt-in caption at the lower
right), the camera sees the orthophoto OrthoLoC made from the UAV flight itself (`dop`), as
the Christchurch rows of the README's table do: `--altitude 100:140 --tilt 5`, 200 poses.

The samples state no ground sample distance and no DSM: the manifests say `--gsd` metres a
pixel (0.18 by default: the OrthoLoC demo's 0.1815 m) over flat ground. A wrong GSD scales the
whole world, so the camera flies as if at altitude x gsd_true / gsd; the 2-D EPE in pixels
and the success rates do not depend on it otherwise.

usage: scripts/eval_ortholoc.py [--terralign BIN] [--shared DIR] [--count N] [--seed S]
                                [--gsd M] [--methods LIST] [--json-dir DIR] [-- EVAL OPTIONS]
Python standard library only."""
import argparse
import json
import os
import subprocess
import sys
import tempfile

SAMPLES = ['L08_0126', 'L15_0004', 'L34_0128']


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--terralign', default=os.path.join(here, '..', 'build', 'release', 'tools', 'terralign', 'terralign'))
    ap.add_argument('--shared', default=os.environ.get('TERRALIGN_SHARED_DATA', os.path.join(here, '..', '..', 'shared', 'data')))
    ap.add_argument('--count', type=int, default=200)
    ap.add_argument('--seed', type=int, default=7)
    ap.add_argument('--gsd', type=float, default=0.18, help='metres a pixel of both orthophotos (not stated; default 0.18)')
    ap.add_argument('--methods', default='init,classic:20,nn:20')
    ap.add_argument('--json-dir', help="keep each eval's JSON here")
    ap.add_argument('extra', nargs='*', help='more eval options, after --')
    args = ap.parse_args()
    if not args.gsd > 0 or args.gsd > 10:
        sys.exit(f'eval_ortholoc: --gsd {args.gsd} must be in (0, 10] metres')
    S = os.path.join(args.shared, 'ortholoc_germany_uav_dop_xdop', 'web_samples')
    if not os.path.isdir(S):
        sys.exit(f'eval_ortholoc: {S} not found (the OrthoLoC samples are read in place from ../shared/data)')
    if not os.access(args.terralign, os.X_OK):
        sys.exit(f'eval_ortholoc: {args.terralign} is not an executable (build first: bash scripts/test.sh)')
    camera = os.path.join(here, '..', 'data', 'cameras', 'uav_752x480.json')
    work = tempfile.mkdtemp(prefix='terralign_ortholoc_')
    out_dir = args.json_dir or work
    os.makedirs(out_dir, exist_ok=True)
    rows = []
    for name in SAMPLES:
        files = {layer: os.path.join(S, f'{name}_{layer}.jpg') for layer in ('dop', 'xdop')}
        for f in files.values():
            if not os.path.isfile(f):
                sys.exit(f'eval_ortholoc: {f} is missing')
        side = 1024 * args.gsd
        manifest = {
            'name': f'OrthoLoC {name}: the UAV flight\'s orthophoto and the state DOP of another date, '
                    f'{args.gsd} m/px assumed, flat ground (CC BY-NC-SA 4.0, evaluation only)',
            'crs': 'local',
            'dem': {'constant': 0.0},
            'layers': [{'name': layer, 'file': f, 'transform': [0.0, args.gsd, 0.0, side, 0.0, -args.gsd]}
                       for layer, f in files.items()],
        }
        m = os.path.join(work, f'{name}.json')
        with open(m, 'w') as fh:
            json.dump(manifest, fh, indent=1)
        js = os.path.join(out_dir, f'{name}_s{args.seed}.json')
        cmd = [args.terralign, 'eval', '--map', m, '--camera', camera, '--ref-layer', 'xdop', '--query-layer', 'dop',
               '--count', str(args.count), '--seed', str(args.seed), '--altitude', '100:140', '--tilt', '5',
               '--methods', args.methods, '--threads', '2', '--json', js] + args.extra
        print(' '.join(cmd), file=sys.stderr)
        run = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        if run.returncode != 0:
            sys.exit(f'eval_ortholoc: {name}: eval failed ({run.returncode}): {run.stderr.strip()[-400:]}')
        with open(js) as fh:
            j = json.load(fh)
        for method, r in j['methods'].items():
            rows.append((name, method, r))
    print(f'OrthoLoC web samples, map: state DOP (xdop), camera: the UAV flight\'s orthophoto (dop); '
          f'{args.count} poses, seed {args.seed}, altitude 100-140 m, tilt <= 5 deg, {args.gsd} m/px assumed\n')
    print('| sample | method | 3-D EPE m (mean / median) | 2-D EPE px (median) | within 5 px | converged | right (converged and within 5 px, of the converged) |')
    print('|---|---|---|---|---|---|---|')
    for name, method, r in rows:
        if method == 'init':
            continue
        print(f"| {name} | {method} | {r['epe_m']['mean']:.2f} / {r['epe_m']['median']:.2f} | {r['epe_px']['median']:.2f} | "
              f"{100 * r['success_rate_5px']:.1f} % | {100 * r['converged_fraction']:.1f} % | {100 * r['converged_within_5px']:.1f} % |")
    init = next(r for name, method, r in rows if method == 'init')
    print(f"\n(The priors, the same poses on every sample: 3-D EPE {init['epe_m']['mean']:.2f} / {init['epe_m']['median']:.2f} m, "
          f"2-D EPE median {init['epe_px']['median']:.2f} px.)")


if __name__ == '__main__':
    main()
