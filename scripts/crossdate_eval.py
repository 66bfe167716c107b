"""What the cross-date evaluations of real orthophoto pairs share (scripts/eval_ortholoc.py,
scripts/eval_fotbcd.py): their common options, a local flat-ground manifest of one pair, one
`terralign eval` run read back from its JSON, and the Markdown table of the rows.

The pairs are read in place from ../shared/data under non-commercial licences: evaluation only,
nothing of them is copied into the repository. Python standard library only."""
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
CAMERA = os.path.join(HERE, '..', 'data', 'cameras', 'uav_752x480.json')


def add_common_args(ap, count):
    """The options every cross-date evaluation takes."""
    ap.add_argument('--terralign', default=os.path.join(HERE, '..', 'build', 'release', 'tools', 'terralign', 'terralign'))
    ap.add_argument('--shared', default=os.environ.get('TERRALIGN_SHARED_DATA', os.path.join(HERE, '..', '..', 'shared', 'data')))
    ap.add_argument('--count', type=int, default=count, help=f'poses a pair (default {count})')
    ap.add_argument('--seed', type=int, default=7)
    ap.add_argument('--methods', default='init,classic:20,nn:20')
    ap.add_argument('--json-dir', help="keep each eval's JSON here")
    ap.add_argument('extra', nargs='*', help='more eval options, after --')


def check_terralign(prog, path):
    if not os.access(path, os.X_OK):
        sys.exit(f'{prog}: {path} is not an executable (build first: bash scripts/test.sh)')


def flat_manifest(path, name, layers, pixel_m, side_px, offsets=None, registration_sigma_m=None):
    """Writes a local-frame manifest of square rasters of side_px pixels of pixel_m metres over
    flat ground at height 0; layers: [(layer name, file)]; offsets: {layer name: (east, north)},
    metres the layer's raster is moved by (none: every layer's corner at (0, side));
    registration_sigma_m: every layer's, as the README's "Map manifests" says (none: not known)."""
    side = side_px * pixel_m
    offsets = offsets or {}
    entries = []
    for layer, f in layers:
        east, north = offsets.get(layer, (0.0, 0.0))
        entry = {'name': layer, 'file': f, 'transform': [east, pixel_m, 0.0, side + north, 0.0, -pixel_m]}
        if registration_sigma_m is not None:
            entry['registration_sigma_m'] = registration_sigma_m
        entries.append(entry)
    manifest = {'name': name, 'crs': 'local', 'dem': {'constant': 0.0}, 'layers': entries}
    with open(path, 'w') as fh:
        json.dump(manifest, fh, indent=1)


def run_eval(prog, args, label, manifest, ref, query, altitude, tilt, json_path):
    """One `terralign eval` of args.count poses; returns its JSON."""
    cmd = [args.terralign, 'eval', '--map', manifest, '--camera', CAMERA, '--ref-layer', ref, '--query-layer', query,
           '--count', str(args.count), '--seed', str(args.seed), '--altitude', altitude, '--tilt', str(tilt),
           '--methods', args.methods, '--threads', '2', '--json', json_path] + args.extra
    print(' '.join(cmd), file=sys.stderr)
    run = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if run.returncode != 0:
        sys.exit(f'{prog}: {label}: eval failed ({run.returncode}): {run.stderr.strip()[-400:]}')
    with open(json_path) as fh:
        return json.load(fh)


def right_share(r):
    """Of the answers reported converged, the share within 5 px (None where none converged)."""
    return r['converged_within_5px'] if r['converged_fraction'] > 0 else None


def percent(x):
    return '-' if x is None else f'{100 * x:.1f} %'


def print_table(rows, first_column):
    """rows: [(label, method, the method's JSON)]; the priors' rows are left out."""
    print(f'| {first_column} | method | 3-D EPE m (mean / median) | 2-D EPE px (median) | within 5 px | converged | right (of the converged) |')
    print('|---|---|---|---|---|---|---|')
    for label, method, r in rows:
        if method == 'init':
            continue
        print(f"| {label} | {method} | {r['epe_m']['mean']:.2f} / {r['epe_m']['median']:.2f} | {r['epe_px']['median']:.2f} | "
              f"{percent(r['success_rate_5px'])} | {percent(r['converged_fraction'])} | {percent(right_share(r))} |")
