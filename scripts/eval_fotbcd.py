#!/usr/bin/python3
"""Cross-date pairs from France: `terralign eval` on the 30 FOTBCD figures, each an IGN BD
ORTHO window of 102.4 m at 0.2 m from two campaigns a few years apart (FOTBCD covers 28
French departements; CC BY-NC-SA 4.0: read in place from ../shared/data, cropped into a
temporary directory that is removed afterwards; evaluation only, nothing trained on or tuned
to them).

Each figure is a matplotlib panel of the two campaigns' tiles, resampled from 512 to 515 pixels
(so 102.4 / 515 = 0.1988 m a pixel): "before" at columns 15-529, "after" at 758-1272, rows
49-563 (the white margins around them are checked; the figures' PROVENANCE.md gives rows
21-535, which hold the titles). The map is the older campaign, the camera sees the newer one
over flat ground (no DEM comes with them), as a UAV would fly over a map some years old. The
tiles are half Christchurch's 205 m, so the camera flies at half its height: `--altitude
50:70 --tilt 5`, 752 x 480 (f 651 px: 0.08-0.11 m a pixel against the map's 0.2, a
magnified map, as a UAV at that height sees).

The campaigns are not registered on each other. Where a whole-tile phase correlation finds a
reliable shift (q >= 12, scripts/local_coregistration.py's), the older tile is moved onto the
newer (`--no-coregister`: not), and what the two still disagree on about that shift over 51 m
windows becomes both layers' registration_sigma_m, so the covariance counts it.

Prints a row per pair and method, then each method over all pairs: the share within 5 px and
converged as the pairs' mean (every pair has the same count of poses), the converged answers'
share within 5 px over all of them, the 3-D and 2-D EPE medians over all poses (a failed
answer counted at its prior, as eval counts it), how many pairs reach 90 % within 5 px, and
the converged answers' NEES; all pairs, then the registered ones and the rest; last, each
pair's shift, q and local disagreement.

usage: /usr/bin/python3 scripts/eval_fotbcd.py [--terralign BIN] [--shared DIR] [--count N]
           [--seed S] [--methods LIST] [--json-dir DIR] [--pairs LIST] [--no-coregister]
           [-- EVAL OPTIONS]
Needs numpy and PIL (Debian's python3-numpy, python3-pil)."""
import argparse
import glob
import os
import shutil
import statistics
import sys
import tempfile

import numpy as np
from PIL import Image

from crossdate_eval import add_common_args, check_terralign, flat_manifest, percent, print_table, run_eval
from local_coregistration import shift

SIDE_PX = 515
PIXEL_M = 102.4 / SIDE_PX
TOP = 49
PANELS = {'before': 15, 'after': 758}
MIN_Q = 12.0  # scripts/local_coregistration.py's --min-q
CHI2_6_95 = 12.592  # chi-square, 6 degrees of freedom, 95 %: eval's nees_within_95
LOCAL_WINDOW_PX = 256  # 51 m, about a view at 50-70 m (58-81 x 37-52 m)


def crop_panels(figure, out_dir, stem):
    """The figure's two panels as PNG files in out_dir; exits naming the figure where its
    layout is not the one described above."""
    try:
        rgb = np.asarray(Image.open(figure).convert('RGB'))
    except OSError as e:
        sys.exit(f'eval_fotbcd: {figure}: not a readable image ({e})')
    if rgb.shape[:2] != (804, 2029):
        sys.exit(f'eval_fotbcd: {figure}: {rgb.shape[1]} x {rgb.shape[0]} pixels, expected 2029 x 804')
    files = []
    for layer, left in PANELS.items():
        panel = rgb[TOP:TOP + SIDE_PX, left:left + SIDE_PX]
        margin = np.concatenate([rgb[TOP - 1, left:left + SIDE_PX], rgb[TOP + SIDE_PX, left:left + SIDE_PX],
                                 rgb[TOP:TOP + SIDE_PX, left - 1], rgb[TOP:TOP + SIDE_PX, left + SIDE_PX]])
        edge = np.concatenate([panel[0], panel[-1], panel[:, 0], panel[:, -1]])
        if not (margin == 255).all() or (edge == 255).all(axis=1).mean() > 0.5:
            sys.exit(f'eval_fotbcd: {figure}: the {layer} panel is not at columns {left}-{left + SIDE_PX - 1}, '
                     f'rows {TOP}-{TOP + SIDE_PX - 1} inside a white margin')
        path = os.path.join(out_dir, f'{stem}_{layer}.png')
        Image.fromarray(np.ascontiguousarray(panel)).save(path)
        files.append((layer, path))
    return files


def campaigns_shift(layers):
    """Where the older campaign's tile places the ground against where the newer one places it,
    as a whole, and how much the two share: (east, north) metres and q of the whole-tile phase
    correlation (scripts/local_coregistration.py's: 4-6 for unrelated content; under 12, no
    reliable shift), and what the two disagree on about that shift over windows of a view's
    size, 51 m: the RMS per axis in metres of the reliable windows' shifts against the whole
    tile's (None with fewer than two reliable windows)."""
    a, b = (np.asarray(Image.open(f).convert('L'), np.float64) for _, f in layers)
    rows, cols, q = shift(a, b)  # the newer tile's content against the older one's, pixels
    n = LOCAL_WINDOW_PX
    windows = [shift(a[y:y + n, x:x + n], b[y:y + n, x:x + n])
               for y in range(0, SIDE_PX - n + 1, n // 2) for x in range(0, SIDE_PX - n + 1, n // 2)]
    d = np.array([(wr - rows, wc - cols) for wr, wc, wq in windows if wq >= MIN_Q])
    local_rms = float(np.sqrt(np.mean(np.sum(d ** 2, axis=1)) / 2)) * PIXEL_M if len(d) >= 2 else None
    return -cols * PIXEL_M, rows * PIXEL_M, float(q), local_rms


def pooled(results):
    """One method's rows over every pair: (within 5 px, converged, right, 3-D EPE median,
    2-D EPE median, pairs at 90 % or more, the converged answers' NEES median and share inside
    their own 95 % ellipsoid)."""
    within = statistics.mean(r['success_rate_5px'] for r in results)
    converged = statistics.mean(r['converged_fraction'] for r in results)
    conv = [s for r in results for s in r['samples'] if s['converged']]
    right = sum(s['epe_px'] < 5 for s in conv) / len(conv) if conv else None
    epe_m = statistics.median(s['epe_m'] for r in results for s in r['samples'])
    epe_px = statistics.median(s['epe_px'] for r in results for s in r['samples'])
    at_90 = sum(r['success_rate_5px'] >= 0.9 for r in results)
    nees = [s['nees'] for s in conv if 'nees' in s]
    nees_median = statistics.median(nees) if nees else None
    inside_95 = sum(v < CHI2_6_95 for v in nees) / len(nees) if nees else None
    return within, converged, right, epe_m, epe_px, at_90, nees_median, inside_95


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_common_args(ap, count=50)
    ap.add_argument('--pairs', help='only these figures, e.g. Binary/test/114,Instances/val/16')
    ap.add_argument('--no-coregister', action='store_true',
                    help='leave the older campaign where its tile is, even where phase correlation registers it')
    args = ap.parse_args()
    root = os.path.join(args.shared, 'fotbcd_france_bdortho_pairs', 'visualizations')
    figures = sorted(glob.glob(os.path.join(root, 'FOTBCD-*', '*', '*.png')))
    if not figures:
        sys.exit(f'eval_fotbcd: no figures under {root} (the FOTBCD pairs are read in place from ../shared/data)')
    labels = {f: os.path.relpath(f, root)[len('FOTBCD-'):-len('.png')] for f in figures}
    if args.pairs:
        wanted = args.pairs.split(',')
        unknown = [w for w in wanted if w not in labels.values()]
        if unknown:
            sys.exit(f'eval_fotbcd: --pairs {",".join(unknown)}: no such figure under {root}')
        figures = [f for f in figures if labels[f] in wanted]
    check_terralign('eval_fotbcd', args.terralign)
    work = tempfile.mkdtemp(prefix='terralign_fotbcd_')
    try:
        out_dir = args.json_dir or work
        os.makedirs(out_dir, exist_ok=True)
        rows, shifts = [], {}
        for f in figures:
            label = labels[f]
            stem = label.replace('/', '_')
            layers = crop_panels(f, work, stem)
            east, north, q, local_rms = shifts[label] = campaigns_shift(layers)
            # Where phase correlation registers the two campaigns, the older one is moved onto
            # the newer, as WHU-CD's providers co-registered Christchurch's surveys: a tracker
            # aligned to the map is then not held to a whole-tile offset between the campaigns.
            # What they still disagree on over a view's windows is split evenly between the two
            # layers' registration_sigma_m, as data/christchurch's manifests state theirs.
            register = q >= MIN_Q and not args.no_coregister
            m = os.path.join(work, f'{stem}.json')
            flat_manifest(m, f'FOTBCD {label}: IGN BD ORTHO, two campaigns, {PIXEL_M:.4f} m/px, flat ground '
                             '(CC BY-NC-SA 4.0, evaluation only)', layers, PIXEL_M, SIDE_PX,
                          {'before': (-east, -north)} if register else None,
                          local_rms / np.sqrt(2) if register and local_rms is not None else None)
            j = run_eval('eval_fotbcd', args, label, m, 'before', 'after', '50:70', 5,
                         os.path.join(out_dir, f'{stem}_s{args.seed}.json'))
            rows += [(label, method, r) for method, r in j['methods'].items()]
    finally:
        shutil.rmtree(work)
    print(f'FOTBCD (IGN BD ORTHO, France), map: the older campaign, camera: the newer; {len(figures)} pairs, '
          f'{args.count} poses each, seed {args.seed}, altitude 50-70 m, tilt <= 5 deg, {PIXEL_M:.4f} m/px\n')
    print_table(rows, 'pair')
    print('\nOver all pairs (within 5 px and converged: the pairs\' mean; right: of every converged answer; '
          'EPE medians: over every pose; NEES: of the converged answers, 5.35 at the median and 95 % inside '
          'where the covariance is honest)\n')
    print('| method, pairs | within 5 px | converged | right | 3-D EPE m median | 2-D EPE px median | pairs at 90 % within 5 px '
          '| NEES median | inside its 95 % |')
    print('|---|---|---|---|---|---|---|---|---|')
    methods = list(dict.fromkeys(method for _, method, _ in rows))
    shared = {label for label, (_, _, q, _) in shifts.items() if q >= MIN_Q}
    for method in methods:
        for name, keep in (('all', lambda label: True), (f'q >= {MIN_Q:g}', lambda label: label in shared),
                           (f'q < {MIN_Q:g}', lambda label: label not in shared)):
            results = [r for label, m, r in rows if m == method and keep(label)]
            if not results or (method == 'init' and name != 'all'):
                continue
            within, converged, right, epe_m, epe_px, at_90, nees_median, inside_95 = pooled(results)
            print(f'| {method}, {name} ({len(results)} pairs) | {percent(within)} | {percent(converged)} | {percent(right)} | '
                  f'{epe_m:.2f} | {epe_px:.2f} | {at_90} of {len(results)} | '
                  f'{"-" if nees_median is None else f"{nees_median:.1f}"} | {percent(inside_95)} |')
    print(f'\nThe campaigns against each other (whole-tile phase correlation of the grey panels; q >= {MIN_Q:g}: '
          f'a reliable shift, they share what it sees)\n')
    print(f'| pair | the older campaign against the newer, east / north m | q | {LOCAL_WINDOW_PX} px windows about it, RMS per axis m |')
    print('|---|---|---|---|')
    for label, (east, north, q, local_rms) in shifts.items():
        print(f'| {label} | {east:+.2f} / {north:+.2f} | {q:.1f} | {"-" if local_rms is None else f"{local_rms:.2f}"} |')


if __name__ == '__main__':
    main()
