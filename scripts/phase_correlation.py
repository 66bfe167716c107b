"""Phase correlation of two equal-size grey images, shared by scripts/naip_coregistration.py and
scripts/local_coregistration.py. Needs numpy (Debian's python3-numpy)."""
import numpy as np


def phase_correlate(a, b):
    """(dx, dy, q): where a's content lies against b's, in pixels (b = a moved 3 columns right
    gives (-3, 0); the wrapped peak of the Hann-windowed, whitened cross-power spectrum F(a)
    conj(F(b)), a parabola through it and its neighbours for the sub-pixel part), and q, the
    peak over the correlation surface's standard
    deviation (4-6 for unrelated content, rising slowly with the size; in the hundreds for
    identical content)."""
    h = np.outer(np.hanning(a.shape[0]), np.hanning(a.shape[1]))
    R = np.fft.fft2(a * h) * np.conj(np.fft.fft2(b * h))
    R /= np.abs(R) + 1e-9
    r = np.real(np.fft.ifft2(R))
    i, j = np.unravel_index(np.argmax(r), r.shape)

    def sub(c, n, axis):
        cm = r[(i - 1) % r.shape[0], j] if axis == 0 else r[i, (j - 1) % r.shape[1]]
        cp = r[(i + 1) % r.shape[0], j] if axis == 0 else r[i, (j + 1) % r.shape[1]]
        c0 = r[i, j]
        v = c + 0.5 * (cm - cp) / (cm - 2 * c0 + cp)
        return v - n if v > n / 2 else v

    return sub(j, r.shape[1], 1), sub(i, r.shape[0], 0), r[i, j] / (r.std() + 1e-12)
