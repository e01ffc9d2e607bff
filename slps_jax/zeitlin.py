r"""Zeitlin's quantisation of vorticity on the sphere: the basis, the Laplacian, fields.

A vorticity field $\omega(\theta, \phi) = \sum_{\ell m}\omega_{\ell m}Y_{\ell m}$ in real
spherical harmonics (coefficient vector indexed $\ell^2 + \ell + m$, $\ell < N$) becomes the
traceless skew-Hermitian matrix $W = \sum_{\ell m}\omega_{\ell m}T_{\ell m}$ of su(N), $T_{\ell m}$
the quantised harmonics of Hoppe & Yau. The conventions (basis, signs, normalisation) are
those of quflow (Modin & Viviani), so that coefficients, matrices, energies and times can be
moved between the two:

- `shr2mat(omega, N)` / `mat2shr(W, L)`: coefficients to matrix and back (degrees
  below `L`); `truncate(W, N)`: a state at another resolution N;
- `laplacian(P)` ($\Delta_N$, eigenvalues $-\ell(\ell+1)$ on $T_{\ell m}$) and
  `solve_poisson(W)` ($\Delta_N^{-1}$ on traceless matrices), both $O(N^2)$: $\Delta_N$ maps
  each diagonal of a matrix to itself and is tridiagonal there (`solve_poisson`'s route
  `"eigenbasis"`, $O(N^3)$ matrix products, uses the table `poisson_eigenbasis(N)`);
- `inner(P, W)` $= \operatorname{Re}\sum_{ij}P_{ij}\bar W_{ij}/N$ (quflow's `inner_L2`),
  `energy(W)` $= -\tfrac12\langle W, \Delta_N^{-1}W\rangle$, `enstrophy(W)`
  $= \tfrac12\langle W, W\rangle$;
- `hbar(N)` $= 2/\sqrt{N^2-1}$: one unit of quflow's "qtime" is $\hbar$ seconds;
- `grid(n_lat, n_lon)` and `field(omega, theta, phi)`: the vorticity field on a
  latitude–longitude grid, for plots.

Everything is JAX (jit, vmap and grad apply) except the one-off basis tables, computed with
NumPy/SciPy once per `N` and cached. See `docs/zeitlin.md` for the derivations.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg

__all__ = [
    "ROUTES",
    "elm2ind",
    "energy",
    "energy_spectrum",
    "enstrophy",
    "enstrophy_spectrum",
    "field",
    "grid",
    "hbar",
    "inner",
    "laplacian",
    "mat2shr",
    "planetary_vorticity",
    "poisson_eigenbasis",
    "shr2mat",
    "solve_poisson",
    "truncate",
]


def hbar(N):
    r"""$\hbar = 2/\sqrt{N^2-1}$: physical time = quflow's qtime $\cdot\ \hbar$.

    **Arguments:** `N`, the matrix size, an integer $\ge 2$.

    **Returns:** $\hbar$, a Python float (seconds per unit of quflow's qtime).
    """
    return 2.0 / math.sqrt(N * N - 1)


def elm2ind(el, m):
    r"""The index $\ell^2 + \ell + m$ of the coefficient $\omega_{\ell m}$ in a vector of
    real spherical-harmonic coefficients (`shr2mat`, `mat2shr`, `field`).

    **Arguments:** `el`, the degree $\ell \ge 0$, and `m`, the order, $-\ell \le m \le \ell$:
    integers, or integer NumPy arrays (elementwise).

    **Returns:** the index (an array for arrays).
    """
    return el * el + el + m


# --- the Laplacian, diagonal by diagonal


@functools.cache
def _tridiagonal(N):
    r"""The Laplacian on the lower diagonal $m$ (entries $W_{t+m, t}$, $t < N - m$), as
    `(d, e)`: `d[m, t]` the diagonal, `e[m, t]` the coupling of $t$ and $t + 1$; padded to
    length `N` (padding: `d = 1`, `e = 0`). With $a_k = \sqrt{k(N-k)}$ and
    $\mu_i = (N-1)/2 - i$: $d = -2s(s+1) + 2\mu_{t+m}\mu_t$, $e = a_{t+1}a_{t+m+1}$ (the
    spin-$s$ Casimir $-\sum_a[S_a, [S_a, \cdot]]$, $s = (N-1)/2$)."""
    s = (N - 1) / 2
    t = np.arange(N)[None, :]
    m = np.arange(N)[:, None]
    mu = lambda i: s - i
    a = lambda k: np.sqrt(np.clip(k * (N - k), 0, None))
    d = np.where(t + m < N, -2 * s * (s + 1) + 2 * mu(t + m) * mu(t), 1.0)
    e = np.where(t + m + 1 < N, a(t + 1) * a(t + m + 1), 0.0)
    return d, e


@jax.jit
def laplacian(P):
    r"""The Laplacian $\Delta_N P = -\sum_a [S_a, [S_a, P]]$:
    $(\Delta_N P)_{ij} = (-2s(s+1) + 2\mu_i\mu_j)P_{ij} + a_{i+1}a_{j+1}P_{i+1,j+1}
    + a_i a_j P_{i-1,j-1}$ ($s = (N-1)/2$, $\mu_i = s - i$, $a_k = \sqrt{k(N-k)}$), in
    $O(N^2)$; its eigenvalues are $-\ell(\ell+1)$ on $T_{\ell m}$.

    **Arguments:** `P`, `(..., N, N)` matrices.

    **Returns:** $\Delta_N P$, the shape and dtype of `P`.
    """
    P = jnp.asarray(P)
    N = P.shape[-1]
    s = (N - 1) / 2
    mu = s - np.arange(N)
    a = np.sqrt(np.arange(N + 1) * (N - np.arange(N + 1)))  # a_0 .. a_N (a_0 = a_N = 0)
    diag = -2 * s * (s + 1) + 2 * np.outer(mu, mu)
    up = np.outer(a[1:], a[1:])  # a_{i+1} a_{j+1}, couples P_{i+1, j+1}
    down = np.outer(a[:-1], a[:-1])  # a_i a_j, couples P_{i-1, j-1}
    pad = [(0, 0)] * (P.ndim - 2) + [(1, 1), (1, 1)]
    Pp = jnp.pad(P, pad)
    return (diag * P + up * Pp[..., 2:, 2:] + down * Pp[..., :-2, :-2]).astype(P.dtype)


def _lower_diagonals(W):
    """`D[..., m, t] = W[..., t + m, t]` (zero past the end), shape `(..., N, N)`."""
    N = W.shape[-1]
    t = np.arange(N)[None, :]
    m = np.arange(N)[:, None]
    rows = np.minimum(t + m, N - 1)
    return jnp.where(jnp.asarray(t + m < N), W[..., rows, np.broadcast_to(t, rows.shape)], 0)


def _from_lower_diagonals(D, N):
    """The skew-Hermitian matrix whose lower diagonals are `D` (`_lower_diagonals`'s
    inverse on skew-Hermitian matrices): two gathers with fixed indices, no scatter
    (`W[i, j] = D[i - j, j]` below the diagonal and on it, `-conj(D[j - i, i])` above)."""
    i = np.arange(N)[:, None]
    j = np.arange(N)[None, :]
    low = D[..., np.abs(i - j), np.minimum(i, j)]  # D[i - j, j] for i >= j, D[j - i, i] else
    return jnp.where(jnp.asarray(i >= j), low, -jnp.conj(low))


ROUTES = ("sweep", "scan", "eigenbasis")
"""The routes of `solve_poisson` (its `route=`, besides `"auto"`)."""


def _route(route):
    """`"auto"`: `"sweep"` on the CPU, `"scan"` elsewhere (on an H200 a sequential loop of
    N steps costs N kernel launches; the scans take 0.37 ms at N = 512, two products
    0.14 ms)."""
    if route == "auto":
        return "sweep" if jax.default_backend() == "cpu" else "scan"
    if route not in ROUTES:
        raise ValueError(f"route must be 'auto' or one of {ROUTES}, got {route!r}.")
    return route


@functools.cache
def _height(N):
    r"""$z_i = \hbar(i - s)$, $s = (N-1)/2$: the quantised height $x_3 = \cos\theta$ is the
    diagonal matrix $Z = i\operatorname{diag}(z)$ ($T_{10} = \sqrt3 Z$; quflow's
    `cartesian_generators(N)[2]`)."""
    return hbar(N) * (np.arange(N) - (N - 1) / 2)


def planetary_vorticity(N, omega, dtype=jnp.complex128):
    r"""The planetary vorticity $f = 2\Omega\cos\theta$ of a sphere rotating at `omega`
    (radians per second) about the axis $x_3$, quantised: $f = 2\Omega Z$ with
    $Z = T_{10}/\sqrt3$ diagonal, `shr2mat` of $\omega_{10} = 2\Omega/\sqrt3$.

    **Arguments:** `N`, the matrix size; `omega`, the rotation rate (a number, or a traced
    scalar); `dtype`, the complex dtype (default complex128).

    **Returns:** $f$, `(N, N)`, diagonal, traceless and skew-Hermitian.
    """
    z = jnp.asarray(_height(N), jnp.finfo(dtype).dtype)
    return jnp.diag((2j * omega * z).astype(dtype))


@functools.cache
def _poisson_blocks(N, gamma=0.0):
    r"""The blocks of the Poisson solve (`solve_poisson`): `(d, e)` of `_tridiagonal`, with
    `d[0, 0]` lowered by 1/2 (the trace fix) for `gamma = 0`, and for `gamma > 0` the
    quasi-geostrophic term: `d[m, t]` lowered by $\tfrac\gamma2(z_{t+m}^2 + z_t^2)$ (the
    entries $-\tfrac\gamma2(z_i^2 + z_j^2)P_{ij}$ of $\tfrac\gamma2(Z^2P + PZ^2)$), which
    makes every block definite."""
    d, e = _tridiagonal(N)
    d = d.copy()
    if gamma:
        z2 = _height(N) ** 2
        t = np.arange(N)[None, :]
        m = np.arange(N)[:, None]
        i = np.minimum(t + m, N - 1)
        d = np.where(t + m < N, d - 0.5 * gamma * (z2[i] + z2[t]), d)
    else:
        d[0, 0] -= 0.5
    return d, e


@functools.cache
def _elimination(N, gamma=0.0):
    r"""The Thomas algorithm's coefficients for the `N` blocks, computed once per `N` in
    float64: the forward sweep $y_t = a_t y_{t-1} + b_t r_t$, the back substitution
    $x_t = y_t - c_t x_{t+1}$, each `(m, t)`. The blocks are symmetric and definite (the
    trace-fixed $m = 0$ one too), so elimination without pivoting is stable ($|c_t| < 1$);
    both routes agree with LAPACK's tridiagonal solver to 2e-15 relative at N = 64 ... 1024,
    and in single precision err by 7e-7 (LAPACK's float32 elimination: 1e-4)."""
    d, e = _poisson_blocks(N, gamma)
    den = np.empty_like(d)
    c = np.zeros_like(d)
    for t in range(N):
        den[:, t] = d[:, t] - (e[:, t - 1] * c[:, t - 1] if t else 0.0)
        c[:, t] = e[:, t] / den[:, t]
    a = np.zeros_like(d)
    a[:, 1:] = -e[:, :-1] / den[:, 1:]
    return a, 1.0 / den, c


@functools.cache
def _elimination_by_entry(N, gamma=0.0):
    """`_elimination`'s coefficients at each entry `(i, j)` of a matrix: those of the
    position `min(i, j)` on the diagonal `|i - j|` (the block of the upper diagonal `-m` is
    that of the lower diagonal `m`)."""
    i, j = np.indices((N, N))
    m, t = np.abs(i - j), np.minimum(i, j)
    return tuple(x[m, t] for x in _elimination(N, gamma))


def _linear_recurrence(a, b):
    """`x_t = a_t x_{t-1} + b_t` (`x_{-1} = 0`) along the last axis, by an associative scan:
    O(log N) steps of elementwise work, no sequential loop."""

    def combine(earlier, later):
        return later[0] * earlier[0], later[0] * earlier[1] + later[1]

    return jax.lax.associative_scan(combine, (jnp.broadcast_to(a, b.shape), b), axis=-1)[1]


def _solve_by_scans(W, gamma=0.0):
    """Route `"scan"`: the lower diagonals' systems, both sweeps by associative scans."""
    N = W.shape[-1]
    real = jnp.finfo(W.dtype).dtype
    a, inv, c = (jnp.asarray(x, real) for x in _elimination(N, gamma))
    y = _linear_recurrence(a, inv * _lower_diagonals(W))
    x = _linear_recurrence(-c[..., ::-1], y[..., ::-1])[..., ::-1]
    return _from_lower_diagonals(x, N)


def _solve_by_sweeps(W, gamma=0.0):
    """Route `"sweep"`: every diagonal's system at once, row by row in the matrix's own
    layout (entry `(i, j)` follows `(i - 1, j - 1)`: the previous row shifted by one), as
    two sequential `lax.scan`s over the `N` rows; no gather, no per-system solver call."""
    N = W.shape[-1]
    real = jnp.finfo(W.dtype).dtype
    a, inv, c = (jnp.asarray(x, real) for x in _elimination_by_entry(N, gamma))
    rows = jnp.moveaxis(W, -2, 0)
    zero = jnp.zeros_like(rows[0, ..., :1])

    def forward(y, coefficients):
        at, it, rt = coefficients
        y = at * jnp.concatenate([zero, y[..., :-1]], -1) + it * rt
        return y, y

    def back(x, coefficients):
        ct, yt = coefficients
        x = yt - ct * jnp.concatenate([x[..., 1:], zero], -1)
        return x, x

    _, y = jax.lax.scan(forward, jnp.zeros_like(rows[0]), (a, inv, rows))
    _, x = jax.lax.scan(back, jnp.zeros_like(rows[0]), (c, y), reverse=True)
    return jnp.moveaxis(x, 0, -2)


def _cyclic_indices(N):
    """Rows and columns of the cyclic diagonals: `C[m, t] = W[(t + m) % N, t]` holds the
    lower diagonal `m` (`t < N - m`) followed by the upper diagonal `N - m`."""
    m, t = np.indices((N, N))
    return (t + m) % N, t


def _eigenbasis(N):
    r"""`(V, inv)` in float64: `V[m]` (N x N, orthogonal) the eigenvectors of $\Delta_N$ on
    the cyclic diagonal `m`, `inv[m]` the inverses of their eigenvalues. The cyclic diagonal
    is the lower diagonal `m` and the upper diagonal `N - m`, two uncoupled tridiagonal
    blocks, each diagonalised by LAPACK's `stemr`; the eigenvalues are then set to their
    exact values $-\ell(\ell+1)$, $\ell = N - 1, \dots, m$ in ascending order (an error of
    `eps` $\|\Delta_N\|$ in the smallest would cost a relative `eps` $N^2$), and the one of
    $\ell = 0$ (the identity, on the main diagonal) gets the inverse 0: the traceless
    solution."""
    d, e = _tridiagonal(N)
    V = np.zeros((N, N, N))
    inv = np.empty((N, N))

    def block(k):
        n = N - k
        lam, v = scipy.linalg.eigh_tridiagonal(d[k, :n], e[k, : n - 1])
        ell = np.arange(N - 1, k - 1, -1)
        exact = -ell * (ell + 1.0)
        assert np.max(np.abs(lam - exact)) < 1e-8 * N * N, "eigenvalues out of order"
        return np.divide(1.0, exact, out=np.zeros(n), where=ell > 0), v

    for m in range(N):
        n = N - m
        inv[m, :n], V[m, :n, :n] = block(m)
        if m:
            inv[m, n:], V[m, n:, n:] = block(n)
    return V, inv


@functools.lru_cache(maxsize=2)
def _eigenbasis_table(N, dtype_name):
    return tuple(jnp.asarray(x, jnp.dtype(dtype_name)) for x in _eigenbasis(N))


def poisson_eigenbasis(N, dtype=jnp.float64):
    r"""The tables of route `"eigenbasis"` of `solve_poisson`: the eigenvectors of
    $\Delta_N$ on each cyclic diagonal of a matrix and the inverses of their eigenvalues;
    built once per `N` in float64 (1.5 s at N = 512 on a CPU core), the two most recent
    cached. Inside a `jax.jit` of your own pass them to `solve_poisson(..., eigenbasis=)`
    as arguments: an array the function closes over is compiled into the program as a
    constant.

    **Arguments:**

    - `N`: the matrix size, an integer $\ge 2$ (else `ValueError`).
    - `dtype`: the states' real dtype (default float64).

    **Returns:** `(V, inv)`, JAX arrays in `dtype`: `V` of shape `(N, N, N)`, the
    eigenvectors (`V` takes 1.1 GB at N = 512 in float64, 8.6 GB at N = 1024), and `inv`
    `(N, N)` the inverses of their eigenvalues (0 for the identity).
    """
    if isinstance(N, (bool, np.bool_)) or not isinstance(N, (int, np.integer)) or N < 2:
        raise ValueError(f"poisson_eigenbasis needs an integer N >= 2, got {N!r}.")
    return _eigenbasis_table(int(N), jnp.dtype(dtype).name)


@functools.partial(jax.jit, static_argnames=("route", "gamma"))
def _solve_tridiagonal(W, route, gamma=0.0):
    return _solve_by_sweeps(W, gamma) if route == "sweep" else _solve_by_scans(W, gamma)


@functools.cache
def _cyclic_degrees(N):
    r"""The degree $\ell$ of each eigenvector of $\Delta_N$ in `poisson_eigenbasis(N)`:
    `ell[m, k]` for the eigenvector `V[m, :, k]` of the cyclic diagonal `m`, whose
    eigenvalue is $-\ell(\ell+1)$ (`N - 1` down to `m` on the lower diagonal `m`, then
    `N - 1` down to `N - m` on the upper diagonal `N - m`). A function of the Laplacian,
    $g(\Delta_N)$, multiplies the coefficient `k` of the cyclic diagonal `m` by
    $g(-\ell(\ell+1))$ (`LinearTerms.rates`)."""
    ell = np.empty((N, N), dtype=np.int64)
    for m in range(N):
        n = N - m
        ell[m, :n] = np.arange(N - 1, m - 1, -1)
        if m:
            ell[m, n:] = np.arange(N - 1, n - 1, -1)
    return ell


def _to_eigenbasis(W, V):
    r"""The coefficients of `W` in the eigenbasis `V` of $\Delta_N$ (`poisson_eigenbasis`),
    cyclic diagonal by diagonal: `(..., N, N, 2)` (real and imaginary parts; `(..., N, N, 1)`
    for a real `W`); one gather and one batched product."""
    N = W.shape[-1]
    rows, cols = _cyclic_indices(N)
    C = W[..., rows, cols]
    parts = jnp.stack([jnp.real(C), jnp.imag(C)], -1) if jnp.iscomplexobj(W) else C[..., None]
    return jnp.einsum("mtk,...mtc->...mkc", V.astype(parts.dtype), parts, precision="highest")


def _from_eigenbasis(Y, V, complex_=True):
    """`_to_eigenbasis`'s inverse: the matrix of the coefficients `Y` (one batched product and
    one gather)."""
    N = Y.shape[-2]
    X = jnp.einsum("mtk,...mkc->...mtc", V.astype(Y.dtype), Y, precision="highest")
    X = jax.lax.complex(X[..., 0], X[..., 1]) if complex_ else X[..., 0]
    i, j = np.indices((N, N))
    return X[..., (i - j) % N, j]


@functools.cache
def _skew_gather(N):
    """How a skew-Hermitian matrix is rebuilt from its cyclic diagonals `m < N // 2 + 1`:
    the entry `(i, j)` lies on the cyclic diagonal `(i - j) % N` at position `j`; where that
    diagonal is not kept, it is `-conj` of the entry `(j, i)`, on the kept diagonal
    `(j - i) % N` at position `i`. **Returns** `(rows, cols, neg)`, `(N, N)` each."""
    i, j = np.indices((N, N))
    m = (i - j) % N
    keep = m < N // 2 + 1
    return np.where(keep, m, (j - i) % N), np.where(keep, j, i), ~keep


@functools.lru_cache(maxsize=2)
def _folded_eigenbasis(N):
    r"""The eigenvectors of $\Delta_N$ on the cyclic diagonals `m < H = N // 2 + 1`, folded
    by their symmetry: each block of a diagonal is persymmetric (unchanged when its order is
    reversed), so each eigenvector is even or odd under the reversal $\sigma$ of its block.
    With representatives $r_j$ of the pairs $\{t, \sigma(t)\}$ (`P = N // 2 + 1` at most),
    an even eigenvector's coefficient is $\sum_j E_{jk}(x_{r_j} + x_{\sigma r_j})$ (once for a
    fixed point) and an odd one's $\sum_j O_{jk}(x_{r_j} - x_{\sigma r_j})$: two tables of
    $HP^2$ numbers, half the table's $HN^2$. NumPy, float64.

    **Returns:** `(E, Od, deg_even, deg_odd, rep, mirror, fixed, slot, sign)`: the tables
    `(H, P, P)`, the degrees of their columns `(H, P)` (0 for padding), the representatives
    and their mirrors `(H, P)` (positions on the cyclic diagonal), `fixed` `(H, P)` (a fixed
    point, or padding), and for each position `t` its pair `slot[m, t]` and `sign[m, t]`
    (+1 for the representative, -1 for the mirror)."""
    V = _eigenbasis(N)[0]
    ell = _cyclic_degrees(N)
    H = P = N // 2 + 1
    E, Od = np.zeros((H, P, P)), np.zeros((H, P, P))
    deg_e, deg_o = np.zeros((H, P), np.int64), np.zeros((H, P), np.int64)
    rep, mirror = np.zeros((H, P), np.int64), np.zeros((H, P), np.int64)
    fixed = np.ones((H, P), bool)
    slot, sign = np.zeros((H, N), np.int64), np.ones((H, N))
    for m in range(H):
        n = N - m
        sigma = np.where(np.arange(N) < n, n - 1 - np.arange(N), N + n - 1 - np.arange(N))
        reps = [t for t in range(N) if t <= sigma[t]]
        for j, t in enumerate(reps):
            rep[m, j], mirror[m, j], fixed[m, j] = t, sigma[t], t == sigma[t]
            slot[m, t] = slot[m, sigma[t]] = j
            if sigma[t] != t:
                sign[m, sigma[t]] = -1.0
        parity = np.sum(V[m] * V[m][sigma], axis=0)  # +1 even, -1 odd (orthonormal columns)
        assert np.all(np.abs(np.abs(parity) - 1) < 1e-8), "eigenvectors of mixed parity"
        even, odd = np.flatnonzero(parity > 0), np.flatnonzero(parity < 0)
        # in the orthonormal bases (e_t +- e_sigma(t))/sqrt 2 (e_t at a fixed point) of the
        # even and odd vectors: the averaged components, made exactly orthogonal (the
        # nearest orthogonal matrix, by an SVD): the computed eigenvectors are symmetric
        # only to their own accuracy, eps |Delta_N| / gap
        pairs = np.asarray([t != sigma[t] for t in reps])
        scale = np.where(pairs, np.sqrt(2.0), 1.0)[:, None]
        for cols, sgn, table in ((even, 1.0, E), (odd, -1.0, Od)):
            rows = [j for j, t in enumerate(reps) if sgn > 0 or t != sigma[t]]
            mirrored = sigma[np.asarray(reps)]
            block = 0.5 * (V[m][reps][:, cols] + sgn * V[m][mirrored][:, cols])
            block = (block * scale)[rows]
            u, _, vt = np.linalg.svd(block, full_matrices=False)
            table[m, rows, : cols.size] = (u @ vt) / scale[rows]
        deg_e[m, : even.size], deg_o[m, : odd.size] = ell[m, even], ell[m, odd]
    return E, Od, deg_e, deg_o, rep, mirror, fixed, slot, sign


def _folded_tables(N, dtype=jnp.float64):
    """`_folded_eigenbasis`'s tables `(E, Od)` as JAX arrays in `dtype` (for
    `_to_skew_eigenbasis`)."""
    E, Od = _folded_eigenbasis(N)[:2]
    return jnp.asarray(E, dtype), jnp.asarray(Od, dtype)


def _folded_degrees(N):
    """The degree of each coefficient of `_to_skew_eigenbasis`, `(2, H, P)` (0 for padding)."""
    return np.stack(_folded_eigenbasis(N)[2:4])


def _by_degree_map(W, values, tables):
    r"""$\sum_\ell v_\ell W_\ell$, $W_\ell$ the degree-$\ell$ part of the skew-Hermitian `W`
    (`values` `(..., N)`, one per degree $0 \dots N - 1$, real): a function of $\Delta_N$, in
    its folded eigenbasis (`tables = _folded_tables(N)`), over leading axes of `W`."""
    N = W.shape[-1]
    y = _to_skew_eigenbasis(W, tables)
    v = jnp.asarray(values)[..., _folded_degrees(N)]
    return _from_skew_eigenbasis(y * v.astype(y.real.dtype), tables, N).astype(W.dtype)


def _real_einsum(spec, table, x):
    """`einsum(spec, table, x)` for a real table and a complex `x`, as two real products
    (each a batched matrix-vector product that reads the table once)."""
    table = table.astype(jnp.real(x).dtype)
    return jax.lax.complex(
        jnp.einsum(spec, table, jnp.real(x), precision="highest"),
        jnp.einsum(spec, table, jnp.imag(x), precision="highest"),
    )


def _to_skew_eigenbasis(W, tables):
    r"""The coefficients of a skew-Hermitian `W` in the eigenbasis of $\Delta_N$ on its cyclic
    diagonals `m < H = N // 2 + 1` (the others are their conjugates), folded by parity
    (`_folded_eigenbasis`; `tables = (E, Od)`): complex `(..., 2, H, P)`, the even
    eigenvectors' coefficients then the odd ones' (their degrees: `_folded_eigenbasis`).
    Four batched matrix-vector products over tables of $2HP^2 \approx N^3/4$ numbers: a
    single state's transform is bound by reading them."""
    E, Od = tables
    N = W.shape[-1]
    H = E.shape[0]
    *_, rep, mirror, fixed, _, _ = _folded_eigenbasis(N)
    rows, cols = _cyclic_indices(N)
    C = W[..., rows[:H], cols[:H]]
    m = np.arange(H)[:, None]
    xr, xm = C[..., m, rep], C[..., m, mirror]
    plus = xr + jnp.where(jnp.asarray(fixed), 0.0, xm)
    even = _real_einsum("mjk,...mj->...mk", E, plus)
    odd = _real_einsum("mjk,...mj->...mk", Od, xr - xm)
    return jnp.stack([even, odd], axis=-3)


def _from_skew_eigenbasis(Y, tables, N):
    """`_to_skew_eigenbasis`'s inverse: the skew-Hermitian `(..., N, N)` matrix of the
    coefficients `Y`."""
    E, Od = tables
    a = _real_einsum("mjk,...mk->...mj", E, Y[..., 0, :, :])
    b = _real_einsum("mjk,...mk->...mj", Od, Y[..., 1, :, :])
    *_, slot, sign = _folded_eigenbasis(N)
    rows, cols, neg = _skew_gather(N)
    s = slot[rows, cols]
    X = a[..., rows, s] + jnp.asarray(sign[rows, cols], a.real.dtype) * b[..., rows, s]
    return jnp.where(jnp.asarray(neg), -jnp.conj(X), X)


@jax.jit
def _solve_by_eigenbasis(W, V, inv):
    """Route `"eigenbasis"`: the cyclic diagonals (one gather), into each one's eigenbasis,
    divided by the eigenvalues and back (two batched products: a matrix product per
    diagonal for a batch of states or under `vmap`), and the matrix (one gather)."""
    Y = _to_eigenbasis(W, V)
    return _from_eigenbasis(Y * inv.astype(Y.dtype)[..., None], V, jnp.iscomplexobj(W))


def solve_poisson(W, route="auto", eigenbasis=None, gamma=0.0):
    r"""$P = \Delta_N^{-1}W$, the traceless solution (for a skew-Hermitian $W$: the stream
    matrix of the vorticity $W$). $\Delta_N$ maps each diagonal to itself tridiagonally;
    on the main diagonal it is singular (the identity): there the first diagonal entry is
    lowered by $\tfrac12$, which leaves the solution exact for a traceless right-hand
    side, and the trace is removed afterwards.

    With `gamma` $= \gamma > 0$, the global quasi-geostrophic model's stream instead:
    $\Delta_N P + \tfrac\gamma2(Z^2P + PZ^2) = W$, $Z = T_{10}/\sqrt3$ the quantised
    height (diagonal, skew-Hermitian): entry by entry
    $(\Delta_N P)_{ij} - \tfrac\gamma2(z_i^2 + z_j^2)P_{ij} = W_{ij}$, tridiagonal on each
    diagonal again and definite, so the solution is unique; its trace is then removed (a
    multiple of the identity in the stream moves nothing). This is what quflow's
    `solve_globalqg(W, gamma)` computes (its docstring writes the term $\gamma ZPZ$, whose
    entries $-\gamma z_iz_jP_{ij}$ differ by $\tfrac\gamma2[Z, [Z, P]]$); both quantise
    $-\gamma x_3^2\psi$.

    **Arguments:**

    - `W`: traceless `(..., N, N)` matrices.
    - `route`: how the systems are solved; the routes agree to round-off:
        - `"auto"` (default): `"sweep"` on the CPU, `"scan"` elsewhere;
        - `"sweep"`: the Thomas algorithm, coefficients computed once per `N` in float64,
          as two sequential loops over the rows, every diagonal at once; $O(N^2)$;
        - `"scan"`: the same sweeps as associative scans on the lower diagonals,
          elementwise work in $O(\log N)$ steps;
        - `"eigenbasis"`: each cyclic diagonal (the lower diagonal `m` and the upper
          diagonal `N - m`) into the eigenbasis of $\Delta_N$ there and back, two batched
          products of $O(N^3)$ work on a table of $N^3$ numbers: for ensembles on
          accelerators, where a batch of states makes each a matrix product per diagonal.
    - `eigenbasis`: route `"eigenbasis"`'s tables `(V, inv)` (`poisson_eigenbasis`), or
      `None` (default: `poisson_eigenbasis(N)` in the real dtype of `W`); the other
      routes ignore it.
    - `gamma`: the quasi-geostrophic parameter $\gamma \ge 0$, a Python number (default 0:
      the Poisson equation); the routes `"sweep"` and `"scan"` only.

    **Returns:** $P$, traceless, the shape of `W`.
    """
    W = jnp.asarray(W)
    N = W.shape[-1]
    route = _route(route)
    gamma = _check_gamma(gamma)
    if gamma:
        if route == "eigenbasis":
            raise ValueError("solve_poisson: gamma > 0 takes the routes 'sweep' or 'scan'.")
        return _traceless(_solve_tridiagonal(W, route, gamma))
    if route == "eigenbasis":  # (traceless already: the identity's inverse eigenvalue is 0)
        if eigenbasis is None:
            eigenbasis = poisson_eigenbasis(N, jnp.finfo(W.dtype).dtype)
        return _solve_by_eigenbasis(W, *eigenbasis)
    return _traceless(_solve_tridiagonal(W, route))


def _check_gamma(gamma):
    r"""The quasi-geostrophic parameter as a Python float, refused unless a finite number
    $\ge 0$ (it sets the solver's tables, so it cannot be traced)."""
    if isinstance(gamma, (bool, np.bool_)) or not isinstance(gamma, (int, float, np.number)):
        raise ValueError(f"gamma must be a finite number >= 0 (a Python number), got {gamma!r}.")
    if not (math.isfinite(gamma) and gamma >= 0):
        raise ValueError(f"gamma must be a finite number >= 0, got {gamma!r}.")
    return float(gamma)


@jax.jit
def _traceless(P):
    N = P.shape[-1]
    tr = jnp.trace(P, axis1=-2, axis2=-1)[..., None, None] / N
    return P - tr * jnp.eye(N, dtype=P.dtype)


# --- inner product, energy, enstrophy (quflow's normalisation)


@jax.jit
def inner(P, W):
    r"""$\langle P, W\rangle = \operatorname{Re}\sum_{ij}P_{ij}\bar W_{ij}/N$ (quflow's
    `inner_L2`: the $L^2$ inner product of the fields divided by $4\pi$).

    **Arguments:** `P`, `W`: `(..., N, N)` matrices (leading axes broadcast).

    **Returns:** the real inner products, shape `(...)`.
    """
    N = W.shape[-1]
    return jnp.sum(jnp.real(P * jnp.conj(W)), axis=(-2, -1)) / N


@jax.jit
def energy(W):
    r"""$E(W) = -\tfrac12\langle W, \Delta_N^{-1}W\rangle$ (quflow's `energy_euler`).

    **Arguments:** `W`, `(..., N, N)` traceless skew-Hermitian matrices (vorticities).

    **Returns:** the real energies, shape `(...)`.
    """
    return -0.5 * inner(W, solve_poisson(W))


@jax.jit
def enstrophy(W):
    r"""The enstrophy $\tfrac12\langle W, W\rangle$ (quflow's `enstrophy`).

    **Arguments:** `W`, `(..., N, N)` matrices (vorticities).

    **Returns:** the real enstrophies, shape `(...)`.
    """
    return 0.5 * inner(W, W)


# --- the quantised spherical harmonics


@functools.cache
def _basis(N, L):
    r"""For each $m < L$, the `(N - m, L - m)` matrix whose column $\ell - m$ is the lower
    diagonal $m$ of $T_{\ell m}$, $\ell < L$ (before quflow's phase), orthonormal columns
    times $\sqrt N$: eigenvectors of the Laplacian's tridiagonal block for its $L - m$
    eigenvalues nearest zero, $-\ell(\ell+1)$, ordered by $\ell$, signed so that the last
    entry has the sign $(-1)^m$ (the orientation of the spherical harmonics)."""
    d, e = _tridiagonal(N)
    out = []
    for m in range(L):
        n = N - m
        if n == 1:
            w = np.ones((1, 1))
        else:  # (the top L - m eigenvalues, ascending: l = L - 1, ..., m)
            _, w = scipy.linalg.eigh_tridiagonal(
                d[m, :n], e[m, : n - 1], select="i", select_range=(n - (L - m), n - 1)
            )
            w = w[:, ::-1]
        w = w * np.sign(w[-1]) * (-1.0) ** m * math.sqrt(N)
        out.append(w)
    return out


@functools.cache
def _harmonic_indices(L):
    r"""`(plus, minus, valid)`, each `(m, l)` for `m, l < L`: the indices of
    $\omega_{\ell m}$ and $\omega_{\ell,-m}$ (0 where $\ell < m$), and $\ell \ge m$."""
    el, m = np.meshgrid(np.arange(L), np.arange(L))
    valid = el >= m
    return (np.where(valid, elm2ind(el, m), 0), np.where(valid, elm2ind(el, -m), 0), valid)


@functools.cache
def _table(N, L):
    r"""`table[m, t, l]`: the lower diagonal `m` of $T_{\ell m}$ (zero-padded), `(L, N, L)`:
    `N L^2` numbers (8.6 GB in float64 at N = L = 1024)."""
    table = np.zeros((L, N, L))
    for m, w in enumerate(_basis(N, L)):
        table[m, : N - m, m:] = w
    return table


def _degrees(n, N):
    """The number of degrees `L` (`L^2 >= n` coefficients), at most `N`."""
    L = math.isqrt(n - 1) + 1 if n else 1
    if L > N:
        raise ValueError(
            f"{n} coefficients need degrees up to {L - 1}; su({N}) resolves "
            f"degrees below {N} ({N * N} coefficients)."
        )
    return L


@functools.partial(jax.jit, static_argnames="N")
def shr2mat(omega, N):
    r"""The matrix $W = \sum_{\ell m}\omega_{\ell m}T_{\ell m}$ of real spherical-harmonic
    coefficients. quflow's `shr2mat`. Only the degrees given are used: with $L^2 \ge n$,
    the tables hold $NL^2$ numbers (the full $N^3$ at $n = N^2$), so a smooth state of a
    large system is cheap to build.

    **Arguments:**

    - `omega`: the coefficients, shape `(..., n)`, $n \le N^2$, index $\ell^2 + \ell + m$
      (`elm2ind`).
    - `N`: the matrix size (a static argument under `jit`).

    **Returns:** $W$, complex `(..., N, N)`, skew-Hermitian; traceless when
    $\omega_{00} = 0$.
    """
    omega = jnp.asarray(omega)
    L = _degrees(omega.shape[-1], N)
    if omega.shape[-1] < L * L:
        omega = jnp.pad(omega, [(0, 0)] * (omega.ndim - 1) + [(0, L * L - omega.shape[-1])])
    plus, minus, valid = _harmonic_indices(L)
    real = jnp.result_type(omega.dtype, float)
    cdtype = jnp.result_type(real, jnp.complex64)
    sgn = np.where(np.arange(L) % 2 == 0, 1.0, -1.0)[:, None]
    wp = jnp.where(valid, omega[..., plus], 0.0)
    wm = jnp.where(valid, omega[..., minus], 0.0)
    # m = 0: the coefficients themselves; m > 0: (w_{l,m} - i w_{l,-m}) / sqrt 2
    zero_m = np.arange(L)[:, None] == 0
    c = jnp.where(zero_m, wp, (wp - 1j * wm) / math.sqrt(2.0)) * sgn  # (..., m, l)
    diag = jnp.einsum("mtl,...ml->...mt", jnp.asarray(_table(N, L), real), c.astype(cdtype))
    # upper diagonal m: 1j * diag; lower: 1j * conj(diag); zero for m >= L
    D = 1j * jnp.conj(diag)
    D = jnp.pad(D, [(0, 0)] * (D.ndim - 2) + [(0, N - L), (0, 0)])
    W = _from_lower_diagonals(D.astype(cdtype), N)
    # the trace is 1j N omega_00 (T_00 = 1j I): exact, not left to rounding
    eye = jnp.eye(N, dtype=cdtype)
    tr = jnp.trace(W, axis1=-2, axis2=-1)[..., None, None] / N
    return W - tr * eye + 1j * omega[..., :1, None].astype(cdtype) * eye


@functools.partial(jax.jit, static_argnames="L")
def mat2shr(W, L=None):
    r"""The real spherical-harmonic coefficients of a skew-Hermitian matrix (`shr2mat`'s
    inverse). quflow's `mat2shr`. The tables hold $NL^2$ numbers.

    **Arguments:**

    - `W`: `(..., N, N)` skew-Hermitian matrices.
    - `L`: the coefficients of degrees $\ell < L$, $1 \le L \le N$ (default: all, $L = N$;
      a static argument under `jit`).

    **Returns:** the real coefficients `(..., L^2)`, index $\ell^2 + \ell + m$ (`elm2ind`).
    """
    W = jnp.asarray(W)
    N = W.shape[-1]
    L = N if L is None else L
    if not 1 <= L <= N:
        raise ValueError(f"mat2shr: L must be 1 ... N = {N}, got {L}.")
    plus, minus, valid = _harmonic_indices(L)
    real = jnp.finfo(W.dtype).dtype
    D = _lower_diagonals(W)[..., :L, :]  # D[m, t] = W[t + m, t] = 1j conj(diag)
    proj = jnp.einsum("...mt,mtl->...ml", D, jnp.asarray(_table(N, L), real)) / N  # (m, l)
    sgn = np.where(np.arange(L) % 2 == 0, 1.0, -1.0)[:, None]
    # m = 0: omega = proj / 1j; m > 0: omega_{l,m} = sqrt2 sgn Im(proj),
    # omega_{l,-m} = -sqrt2 sgn Re(proj)
    zero_m = np.arange(L)[:, None] == 0
    wp = jnp.where(zero_m, jnp.imag(proj), math.sqrt(2.0) * sgn * jnp.imag(proj))
    wm = -math.sqrt(2.0) * sgn * jnp.real(proj)
    # every index l^2 + l + m once: a gather in the coefficients' order, no scatter
    neg = valid & ~zero_m
    return jnp.concatenate([wp[..., valid], wm[..., neg]], axis=-1)[..., _coefficient_order(L)]


@functools.partial(jax.jit, static_argnames="N")
def truncate(W, N):
    r"""An su(M) state at another resolution: the su(N) state of its degrees
    $\ell < \min(M, N)$, `shr2mat(mat2shr(W, L), N)` with $L = \min(M, N)$. For $N < M$ it
    coarse-grains (the finer degrees are dropped: in the $L^2$ norm the nearest su(N)
    field); for $N > M$ the new degrees are zero. The tables hold $(M + N)L^2$ numbers.

    **Arguments:**

    - `W`: the su(M) state, `(..., M, M)`.
    - `N`: the new matrix size, an integer $\ge 2$ (a static argument under `jit`).

    **Returns:** the su(N) state, complex `(..., N, N)`.
    """
    W = jnp.asarray(W)
    if isinstance(N, (bool, np.bool_)) or not isinstance(N, (int, np.integer)) or N < 2:
        raise ValueError(f"truncate: N must be an integer >= 2, got {N!r}.")
    return shr2mat(mat2shr(W, L=min(W.shape[-1], N)), N)


@functools.cache
def _coefficient_order(L):
    """The permutation taking `mat2shr`'s values, those of `m >= 0` then of `m < 0` in the
    `(m, l)` order of `_harmonic_indices`, to the coefficient order `l^2 + l + m`."""
    plus, minus, valid = _harmonic_indices(L)
    neg = valid & (np.arange(L)[:, None] > 0)
    return np.argsort(np.concatenate([plus[valid], minus[neg]]))


# --- fields on the sphere, for plots


def grid(n_lat, n_lon=None):
    r"""A latitude–longitude grid for `field`: colatitudes
    $\theta_k = \pi(k + \tfrac12)/n_{lat}$ and longitudes $\phi_j = 2\pi j/n_{lon}$.

    **Arguments:** `n_lat`, the number of colatitudes; `n_lon`, the number of longitudes
    (default `2 n_lat`).

    **Returns:** `(theta, phi)`, NumPy arrays of shapes `(n_lat,)` and `(n_lon,)`.
    """
    n_lon = 2 * n_lat if n_lon is None else n_lon
    return (np.pi * (np.arange(n_lat) + 0.5) / n_lat, 2 * np.pi * np.arange(n_lon) / n_lon)


@functools.lru_cache(maxsize=8)
def _legendre(L, theta_key):
    r"""$\sqrt{4\pi}\,\bar P_{\ell m}(\cos\theta)$ for $0 \le m \le \ell < L$: the
    orthonormal associated Legendre functions (no Condon–Shortley phase), shape
    `(L, L, n_theta)`, by the standard stable recurrences."""
    theta = np.asarray(theta_key)
    x, y = np.cos(theta), np.sin(theta)
    p = np.zeros((L, L, theta.size))
    p[0, 0] = 1.0 / np.sqrt(4 * np.pi)
    for m in range(1, L):
        p[m, m] = np.sqrt((2 * m + 1) / (2 * m)) * y * p[m - 1, m - 1]
    for m in range(L - 1):
        p[m + 1, m] = np.sqrt(2 * m + 3) * x * p[m, m]
    for m in range(L):
        for el in range(m + 2, L):
            a = np.sqrt((4 * el * el - 1) / (el * el - m * m))
            b = np.sqrt(((el - 1) ** 2 - m * m) / (4 * (el - 1) ** 2 - 1))
            p[el, m] = a * (x * p[el - 1, m] - b * p[el - 2, m])
    return np.sqrt(4 * np.pi) * p


def field(omega, theta, phi):
    r"""The field $\sum_{\ell m}\omega_{\ell m}Y_{\ell m}(\theta, \phi)$ of real
    spherical-harmonic coefficients on a grid, in quflow's real form and normalisation
    ($Y_{\ell m}$ of mean square 1 over the sphere;
    $Y_{\ell m} = \sqrt2\,\bar P_{\ell m}(\cos\theta)\cos m\phi$,
    $Y_{\ell,-m} = -\sqrt2\,\bar P_{\ell m}(\cos\theta)\sin m\phi$ for $m > 0$). quflow's
    plots multiply the coefficients by Berezin factors first; this is the plain series.

    **Arguments:**

    - `omega`: the coefficients, `(..., L^2)` (`mat2shr`).
    - `theta`, `phi`: the colatitudes and longitudes, 1-D arrays of lengths `n_theta` and
      `n_phi` (`grid`); the field is evaluated on `theta` × `phi`.

    **Returns:** the field, shape `(..., n_theta, n_phi)`.
    """
    omega = jnp.asarray(omega)
    L = math.isqrt(omega.shape[-1])
    theta, phi = np.asarray(theta, float), np.asarray(phi, float)
    p = _legendre(L, tuple(theta.tolist()))  # (l, m, theta)
    m = np.arange(L)
    cos, sin = np.cos(np.outer(m, phi)), np.sin(np.outer(m, phi))  # (m, phi)
    plus, minus, valid = (x.T for x in _harmonic_indices(L))  # (l, m)
    f = np.where(m == 0, 1.0, math.sqrt(2.0))[None, :]
    wp = jnp.where(valid, omega[..., plus], 0.0) * f  # (..., l, m)
    wm = jnp.where(valid & (m[None, :] > 0), omega[..., minus], 0.0) * f
    a = jnp.einsum("...lm,lmt->...mt", wp, p)
    b = jnp.einsum("...lm,lmt->...mt", wm, p)
    return jnp.einsum("...mt,mp->...tp", a, cos) - jnp.einsum("...mt,mp->...tp", b, sin)


# --- spectra by degree


def _by_degree(W, weight):
    r"""$\tfrac12\sum_m w_\ell\,\omega_{\ell m}^2$ for each degree $\ell < N$, `(..., N)`."""
    W = jnp.asarray(W)
    N = W.shape[-1]
    omega = mat2shr(W).astype(jnp.finfo(W.dtype).dtype)  # (mat2shr may widen complex64)
    degree = np.repeat(np.arange(N), 2 * np.arange(N) + 1)  # (the degree of index l^2 + l + m)
    terms = jnp.moveaxis(0.5 * omega * omega * jnp.asarray(weight[degree], omega.dtype), -1, 0)
    return jnp.moveaxis(jax.ops.segment_sum(terms, degree, num_segments=N), 0, -1)


@jax.jit
def enstrophy_spectrum(W):
    r"""The enstrophy by degree, $Z_\ell = \tfrac12\sum_{m=-\ell}^{\ell}\omega_{\ell m}^2$,
    $\ell = 0, \dots, N-1$ ($\omega$ = `mat2shr(W)`): $\sum_\ell Z_\ell$ = `enstrophy(W)`.
    The tables are `mat2shr`'s ($N^3$ numbers).

    **Arguments:** `W`, `(..., N, N)` skew-Hermitian matrices.

    **Returns:** $Z_\ell$, real, `(..., N)`.
    """
    N = W.shape[-1]
    return _by_degree(W, np.ones(N))


@jax.jit
def energy_spectrum(W):
    r"""The energy by degree, $E_\ell = \tfrac12\sum_{m=-\ell}^{\ell}\omega_{\ell m}^2 /
    (\ell(\ell+1))$, $\ell = 0, \dots, N-1$ ($E_0 = 0$): $\sum_\ell E_\ell$ = `energy(W)`
    and $E_\ell = Z_\ell/(\ell(\ell+1))$ (`enstrophy_spectrum`). quflow's
    `analysis.energy_spectrum` is $2E_\ell$ for $\ell = 1, \dots, N-1$ (no $\tfrac12$, no
    $\ell = 0$). The tables are `mat2shr`'s ($N^3$ numbers).

    **Arguments:** `W`, `(..., N, N)` skew-Hermitian matrices.

    **Returns:** $E_\ell$, real, `(..., N)`.
    """
    N = W.shape[-1]
    el = np.arange(N)
    return _by_degree(W, np.divide(1.0, el * (el + 1.0), out=np.zeros(N), where=el > 0))
