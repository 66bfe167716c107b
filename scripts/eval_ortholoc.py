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
import os
import sys
import tempfile

from crossdate_eval import add_common_args, check_terralign, flat_manifest, print_table, run_eval

SAMPLES = ['L08_0126', 'L15_0004', 'L34_0128']


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_common_args(ap, count=200)
    ap.add_argument('--gsd', type=float, default=0.18, help='metres a pixel of both orthophotos (not stated; default 0.18)')
    args = ap.parse_args()
    if not args.gsd > 0 or args.gsd > 10:
        sys.exit(f'eval_ortholoc: --gsd {args.gsd} must be in (0, 10] metres')
    S = os.path.join(args.shared, 'ortholoc_germany_uav_dop_xdop', 'web_samples')
    if not os.path.isdir(S):
        sys.exit(f'eval_ortholoc: {S} not found (the OrthoLoC samples are read in place from ../shared/data)')
    check_terralign('eval_ortholoc', args.terralign)
    work = tempfile.mkdtemp(prefix='terralign_ortholoc_')
    out_dir = args.json_dir or work
    os.makedirs(out_dir, exist_ok=True)
    rows = []
    for name in SAMPLES:
        files = [(layer, os.path.join(S, f'{name}_{layer}.jpg')) for layer in ('dop', 'xdop')]
        for _, f in files:
            if not os.path.isfile(f):
                sys.exit(f'eval_ortholoc: {f} is missing')
        m = os.path.join(work, f'{name}.json')
        flat_manifest(m, f'OrthoLoC {name}: the UAV flight\'s orthophoto and the state DOP of another date, '
                         f'{args.gsd} m/px assumed, flat ground (CC BY-NC-SA 4.0, evaluation only)',
                      files, args.gsd, 1024)
        j = run_eval('eval_ortholoc', args, name, m, 'xdop', 'dop', '100:140', 5,
                     os.path.join(out_dir, f'{name}_s{args.seed}.json'))
        for method, r in j['methods'].items():
            rows.append((name, method, r))
    print(f'OrthoLoC web samples, map: state DOP (xdop), camera: the UAV flight\'s orthophoto (dop); '
          f'{args.count} poses, seed {args.seed}, altitude 100-140 m, tilt <= 5 deg, {args.gsd} m/px assumed\n')
    print_table(rows, 'sample')
    init = next(r for name, method, r in rows if method == 'init')
    print(f"\n(The priors, the same poses on every sample: 3-D EPE {init['epe_m']['mean']:.2f} / {init['epe_m']['median']:.2f} m, "
          f"2-D EPE median {init['epe_px']['median']:.2f} px.)")


if __name__ == '__main__':
    main()
