#!/usr/bin/python3
"""How well the ten NAIP years of ../shared/data/naip_nd_2009_2020 are registered to each other.

Each year's grey image is resampled onto one 5 m grid through its own geotransform (the
origins differ by up to 3 m), turned into its gradient magnitude (less sensitive to the
years' colours than the grey levels), and phase-correlated with a reference year (default
2016) over the whole common area, with a parabola through the peak for the sub-pixel shift;
then the same in 4 x 4 blocks for 2009/2020, 2016/2017 and 2012/2020 (q: peak over the
correlation surface's spread; below about 12 the block has no reliable peak).
Needs numpy and PIL (Debian's python3-numpy, python3-pil).
  /usr/bin/python3 scripts/naip_coregistration.py [REFERENCE_YEAR]
"""
import sys, glob, os, numpy as np
from PIL import Image
from phase_correlation import phase_correlate as pc
HERE = os.path.dirname(os.path.abspath(__file__))
files = sorted(glob.glob(os.path.join(HERE, '..', '..', 'shared', 'data', 'naip_nd_2009_2020', 'naip', '*.tif')))
if not files:
    sys.exit('naip_coregistration: no NAIP GeoTIFFs under ../shared/data/naip_nd_2009_2020/naip')
def load(f):
    im = Image.open(f)
    tp = im.tag_v2.get(33922); sc = im.tag_v2.get(33550)
    a = np.asarray(im).astype(np.float64)
    return a[..., :3], tp[3], tp[4], sc[0]
# common grid: 5 m, origin inside all
X0, Y0, N, M = 485910.0, 5209235.0, 600, 700
def resample(a, ox, oy, s):
    # pixel centre (i,j) of the common grid -> source pixel coordinates
    xs = (X0 + 5 * (np.arange(N) + 0.5) - ox) / s - 0.5
    ys = (oy - (Y0 - 5 * (np.arange(M) + 0.5))) / s - 0.5
    xx, yy = np.meshgrid(xs, ys)
    x0 = np.floor(xx).astype(int); y0 = np.floor(yy).astype(int)
    fx = xx - x0; fy = yy - y0
    g = a.mean(axis=2)
    def at(y, x): return g[np.clip(y, 0, g.shape[0]-1), np.clip(x, 0, g.shape[1]-1)]
    return (at(y0,x0)*(1-fx)*(1-fy) + at(y0,x0+1)*fx*(1-fy) + at(y0+1,x0)*(1-fx)*fy + at(y0+1,x0+1)*fx*fy)
def grad(g):
    gx = np.zeros_like(g); gy = np.zeros_like(g)
    gx[:, 1:-1] = g[:, 2:] - g[:, :-2]; gy[1:-1] = g[2:] - g[:-2]
    m = np.hypot(gx, gy)
    return (m - m.mean()) / (m.std() + 1e-9)
imgs = {}
for f in files:
    y = f.split('_')[-1][:4]
    a, ox, oy, s = load(f)
    imgs[y] = grad(resample(a, ox, oy, s))
years = sorted(imgs)
ref = sys.argv[1] if len(sys.argv) > 1 else '2016'
print('global offset of each year against', ref, '(metres east, north; + = year content lies east/north of ref) and peak/std')
for y in years:
    dx, dy, q = pc(imgs[y], imgs[ref])
    print(y, '%6.2f %6.2f  q %.1f' % (5 * dx, -5 * dy, q))
print('blocks (150x175 px = 750x875 m), offset of the second year against the first (m E, m N) and q:')
for A, B in (('2009', '2020'), ('2016', '2017'), ('2012', '2020')):
    rows = []
    for bi in range(4):
        for bj in range(4):
            sl = (slice(bi*175, (bi+1)*175), slice(bj*150, (bj+1)*150))
            dx, dy, q = pc(imgs[B][sl], imgs[A][sl])
            rows.append('(%5.1f,%5.1f q%3.0f)' % (5*dx, -5*dy, q))
    print(A, B)
    for k in range(4):
        print('  ', ' '.join(rows[k * 4:(k + 1) * 4]))
