"""``numpy.random.default_rng([seed, trial, stream])``, compiled: the same numbers, no Python.

Every trial draws from two generators of its own (``uncertainty.trial_rng``). Building a
numpy Generator costs about 20 us and drawing through it adds array temporaries, which was
about 40 % of a hexagon trial. This module reimplements, for numba kernels, exactly what
numpy does for that seeding and for the two draws the project uses:

* ``SeedSequence(entropy)``: the entropy words (each non-negative integer split into 32-bit
  words, least significant first; 0 is one word), the pool of 4 words mixed with the hash
  constants of numpy's ``bit_generator.pyx``, and ``generate_state(4, uint64)``;
* ``PCG64`` seeded from those 4 words (``pcg64_set_seed``: state and increment are 128-bit,
  high word first) and stepped by its 128-bit LCG with the XSL-RR output;
* ``Generator.random()`` = ``(next_uint64 >> 11) * 2**-53`` and
  ``Generator.uniform(low, high)`` = ``low + (high - low) * random()``.

128-bit arithmetic is done on pairs of uint64. The generator state travels as a uint64
array of 4: state high, state low, increment high, increment low. Bit-for-bit agreement with
numpy over seeds of one to three words, trials and streams is tested
(tests/core/test_pcg.py); numpy documents SeedSequence and PCG64 as stable across versions.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from formation_ilc.core._jit import njit

__all__ = ["seed_words", "seed_state", "next_uint64", "next_double", "STATE_SIZE"]

STATE_SIZE = 4

_M32 = np.uint64(0xFFFFFFFF)
# numpy/random/bit_generator.pyx
_INIT_A = np.uint32(0x43B0D7E5)
_MULT_A = np.uint32(0x931E8875)
_INIT_B = np.uint32(0x8B51F9DD)
_MULT_B = np.uint32(0x58F38DED)
_MIX_MULT_L = np.uint32(0xCA01F9DD)
_MIX_MULT_R = np.uint32(0x4973F715)
_XSHIFT = np.uint32(16)
_POOL = 4
# numpy/random/src/pcg64/pcg64.h: PCG_DEFAULT_MULTIPLIER_HIGH / _LOW
_MUL_HI = np.uint64(2549297995355413924)
_MUL_LO = np.uint64(4865540595714422341)
_DOUBLE_UNIT = 1.0 / 9007199254740992.0  # 2**-53


def seed_words(value: int) -> NDArray[np.uint32]:
    """SeedSequence's entropy words of one non-negative integer (least significant first)."""
    value = int(value)
    if value < 0:
        raise ValueError(f"expected a non-negative integer, got {value}")
    words = [value & 0xFFFFFFFF]
    value >>= 32
    while value:
        words.append(value & 0xFFFFFFFF)
        value >>= 32
    return np.array(words, dtype=np.uint32)


@njit(cache=True)
def _hashmix(value: np.uint32, hash_const: NDArray[np.uint32]) -> np.uint32:
    value = np.uint32(value ^ hash_const[0])
    hash_const[0] = np.uint32(hash_const[0] * _MULT_A)
    value = np.uint32(value * hash_const[0])
    return np.uint32(value ^ (value >> _XSHIFT))


@njit(cache=True)
def _mix(x: np.uint32, y: np.uint32) -> np.uint32:
    result = np.uint32(np.uint32(_MIX_MULT_L * x) - np.uint32(_MIX_MULT_R * y))
    return np.uint32(result ^ (result >> _XSHIFT))


@njit(cache=True)
def _mulhi(a: np.uint64, b: np.uint64) -> np.uint64:
    """High 64 bits of the 128-bit product a * b."""
    a_lo = a & _M32
    a_hi = a >> np.uint64(32)
    b_lo = b & _M32
    b_hi = b >> np.uint64(32)
    p0 = a_lo * b_lo
    p1 = a_lo * b_hi
    p2 = a_hi * b_lo
    p3 = a_hi * b_hi
    mid = (p0 >> np.uint64(32)) + (p1 & _M32) + (p2 & _M32)
    return p3 + (p1 >> np.uint64(32)) + (p2 >> np.uint64(32)) + (mid >> np.uint64(32))


@njit(cache=True)
def _step(st: NDArray[np.uint64]) -> None:
    """state = state * multiplier + increment (mod 2**128)."""
    sh = st[0]
    sl = st[1]
    lo = sl * _MUL_LO
    hi = _mulhi(sl, _MUL_LO) + sh * _MUL_LO + sl * _MUL_HI
    lo2 = lo + st[3]
    carry = np.uint64(1) if lo2 < lo else np.uint64(0)
    st[0] = hi + st[2] + carry
    st[1] = lo2


@njit(cache=True)
def _entropy(seed: NDArray[np.uint32], trial: int, stream: int) -> NDArray[np.uint32]:
    """The words of [seed, trial, stream] as SeedSequence assembles them."""
    extra = np.empty(4, dtype=np.uint32)
    m = 0
    for v in (trial, stream):
        x = np.uint64(v)
        extra[m] = np.uint32(x & _M32)
        m += 1
        x >>= np.uint64(32)
        while x != np.uint64(0):
            extra[m] = np.uint32(x & _M32)
            m += 1
            x >>= np.uint64(32)
    out = np.empty(seed.shape[0] + m, dtype=np.uint32)
    out[:seed.shape[0]] = seed
    out[seed.shape[0]:] = extra[:m]
    return out


@njit(cache=True)
def seed_state(seed: NDArray[np.uint32], trial: int, stream: int,
               st: NDArray[np.uint64]) -> None:
    """Seed ``st`` (uint64, STATE_SIZE) as ``np.random.default_rng([seed, trial, stream])``
    seeds its PCG64. seed : the words of :func:`seed_words`; trial, stream >= 0."""
    ent = _entropy(seed, trial, stream)
    hc = np.empty(1, dtype=np.uint32)
    hc[0] = _INIT_A
    pool = np.empty(_POOL, dtype=np.uint32)
    for i in range(_POOL):
        pool[i] = _hashmix(ent[i] if i < ent.shape[0] else np.uint32(0), hc)
    for i_src in range(_POOL):
        for i_dst in range(_POOL):
            if i_src != i_dst:
                pool[i_dst] = _mix(pool[i_dst], _hashmix(pool[i_src], hc))
    for i_src in range(_POOL, ent.shape[0]):
        for i_dst in range(_POOL):
            pool[i_dst] = _mix(pool[i_dst], _hashmix(ent[i_src], hc))
    # generate_state(4, uint64): 8 words, paired little-endian
    hb = _INIT_B
    words = np.empty(8, dtype=np.uint32)
    for i in range(8):
        v = np.uint32(pool[i % _POOL] ^ hb)
        hb = np.uint32(hb * _MULT_B)
        v = np.uint32(v * hb)
        words[i] = np.uint32(v ^ (v >> _XSHIFT))
    s = np.empty(4, dtype=np.uint64)
    for k in range(4):
        s[k] = np.uint64(words[2 * k]) | (np.uint64(words[2 * k + 1]) << np.uint64(32))
    # pcg64_set_seed -> pcg_setseq_128_srandom_r(initstate = s0:s1, initseq = s2:s3)
    st[2] = (s[2] << np.uint64(1)) | (s[3] >> np.uint64(63))
    st[3] = (s[3] << np.uint64(1)) | np.uint64(1)
    st[0] = np.uint64(0)
    st[1] = np.uint64(0)
    _step(st)
    lo = st[1] + s[1]
    carry = np.uint64(1) if lo < st[1] else np.uint64(0)
    st[0] = st[0] + s[0] + carry
    st[1] = lo
    _step(st)


@njit(cache=True)
def next_uint64(st: NDArray[np.uint64]) -> np.uint64:
    """PCG64's next output (step, then XSL-RR of the new state)."""
    _step(st)
    hi = st[0]
    x = hi ^ st[1]
    rot = hi >> np.uint64(58)
    return (x >> rot) | (x << ((np.uint64(64) - rot) & np.uint64(63)))


@njit(cache=True)
def next_double(st: NDArray[np.uint64]) -> float:
    """``Generator.random()``: 53 random bits in [0, 1)."""
    return float(next_uint64(st) >> np.uint64(11)) * _DOUBLE_UNIT
