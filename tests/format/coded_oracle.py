"""Oracle: a coded sparse payload (encoding 5, format 1.2) decoded from docs/FORMAT.md alone.

This decoder follows the text of "Coded sparse payloads (encoding 5, format 1.2)" (the
coder, its end check, the blocks, quads and every context) and shares no code with the
C++ one. ltb_coded_helper encodes small i32 chunks of several shapes (L not a multiple of
W, W = 1, W = L, one line, empty lines, INT32_MIN and INT32_MAX, wavelet-like data); each
payload must decode here to the helper's input, and a truncated or extended payload must
fail the end check.

usage: coded_oracle.py PATH_TO_ltb_coded_helper
"""
import os
import subprocess
import sys
import tempfile

import numpy as np

HELPER = sys.argv[1] if __name__ == "__main__" else None  # importable: tests/python uses decode()


class Damage(Exception):
    pass


class Context:
    __slots__ = ("fast", "slow")

    def __init__(self):
        self.fast = 0x8000
        self.slow = 0x8000


def contexts(*dims):
    if not dims:
        return Context()
    return [contexts(*dims[1:]) for _ in range(dims[0])]


class Decoder:
    def __init__(self, data):
        if len(data) < 5 or data[0] != 0:
            raise Damage("coder start")
        self.data = data
        self.code = int.from_bytes(data[1:5], "big")
        if self.code == 0xFFFFFFFF:
            raise Damage("start value")
        self.range = 0xFFFFFFFF
        self.pos = 5
        self.overrun = False

    def bit(self, c):
        p = (c.fast + c.slow) >> 2
        bound = (self.range >> 15) * p
        if self.code < bound:
            self.range = bound
            b = 0
        else:
            self.code -= bound
            self.range -= bound
            b = 1
        if b == 0:
            c.fast += (65536 - c.fast) >> 4
            c.slow += (65536 - c.slow) >> 7
        else:
            c.fast -= c.fast >> 4
            c.slow -= c.slow >> 7
        while self.range < (1 << 24):
            self.range = (self.range << 8) & 0xFFFFFFFF
            if self.pos < len(self.data):
                nb = self.data[self.pos]
                self.pos += 1
            else:
                nb = 0
                self.overrun = True
            self.code = ((self.code << 8) | nb) & 0xFFFFFFFF
        return b

    def end_check(self):
        if self.overrun or self.pos != len(self.data) or self.code != 0:
            raise Damage("end check")


def bw(v):
    return v.bit_length()


def bucket(s):
    if s <= 2:
        return s
    for limit, b in ((4, 3), (7, 4), (12, 5), (20, 6), (40, 7)):
        if s <= limit:
            return b
    return 8


def mag(s):
    return s % 128


def sgn(s):
    return 0 if s == 0 else (1 if s < 128 else 2)


def decode(payload, E, L):
    """The E i32 elements of a chunk with lines of L elements, from an encoding-5 payload."""
    if len(payload) < 1 or payload[0] != 1:
        raise Damage("model")
    W, shift, i = 0, 0, 1
    while True:
        if i >= len(payload):
            raise Damage("varint")
        b = payload[i]
        i += 1
        W |= (b & 0x7F) << shift
        shift += 7
        if not b & 0x80:
            if i > 2 and b == 0:
                raise Damage("non-canonical varint")
            break
    if W == 0 or W > L:
        raise Damage("W")
    H = (L + W - 1) // W
    BW, BH, QW, QH = (W + 7) // 8, (H + 7) // 8, (W + 3) // 4, (H + 3) // 4
    d = Decoder(payload[i:])
    LINE, BLOCK, QUAD = contexts(2), contexts(8, 2, 3), contexts(8, 2, 3)
    SIG, PREFIX = contexts(10, 3, 2, 3), contexts(7, 9, 16)
    SUFFIX, SIGN = contexts(32, 31), contexts(3, 3)
    out = [0] * E
    prev_state, prev_f, prev_g, prev_F = [0] * L, [0] * (BW * BH), [0] * (QW * QH), 0
    for t in range(E // L):
        state, f, g = [0] * L, [0] * (BW * BH), [0] * (QW * QH)

        def st(x, y):  # state of line t at (x, y), 0 outside the image
            return state[y * W + x] if x >= 0 and y >= 0 else 0

        F = d.bit(LINE[prev_F])
        if F:
            any_block = False
            for by in range(BH):
                for bx in range(BW):
                    if 8 * by * W + 8 * bx >= L:
                        continue
                    left = f[by * BW + bx - 1] if bx > 0 else 0
                    up = f[(by - 1) * BW + bx] if by > 0 else 0
                    if not d.bit(BLOCK[min(bw(max(bx, by)), 7)][prev_f[by * BW + bx]][left + up]):
                        continue
                    f[by * BW + bx] = 1
                    any_block = True
                    any_quad = False
                    for qx, qy in ((2 * bx, 2 * by), (2 * bx + 1, 2 * by), (2 * bx, 2 * by + 1), (2 * bx + 1, 2 * by + 1)):
                        if qx >= QW or qy >= QH or 4 * qy * W + 4 * qx >= L:
                            continue
                        ql = g[qy * QW + qx - 1] if qx > 0 else 0
                        qu = g[(qy - 1) * QW + qx] if qy > 0 else 0
                        if not d.bit(QUAD[min(bw(max(qx, qy)), 7)][prev_g[qy * QW + qx]][ql + qu]):
                            continue
                        g[qy * QW + qx] = 1
                        any_quad = True
                        any_pos = False
                        for y in range(4 * qy, min(4 * qy + 4, H)):
                            for x in range(4 * qx, min(4 * qx + 4, W)):
                                j = y * W + x
                                if j >= L:
                                    continue
                                l, u, ul = st(x - 1, y), st(x, y - 1), st(x - 1, y - 1)
                                near = min((l != 0) + (u != 0) + (ul != 0), 2)
                                parent = int(state[(y // 2) * W + x // 2] != 0)
                                pm = mag(prev_state[j])
                                lv = min(bw(max(x, y)), 9)
                                if not d.bit(SIG[lv][near][parent][min(pm, 2)]):
                                    continue
                                any_pos = True
                                P = PREFIX[min(lv, 6)][bucket(mag(l) + mag(u) + 2 * pm)]
                                k = 0
                                while k < 31 and d.bit(P[min(k, 15)]):
                                    k += 1
                                a = 1
                                for ii in range(k):
                                    a = 2 * a + d.bit(SUFFIX[k][ii])
                                neg = d.bit(SIGN[sgn(prev_state[j])][sgn(l)])
                                if a > 2**31 or (a == 2**31 and not neg):
                                    raise Damage("value")
                                out[t * L + j] = -a if neg else a
                                state[j] = min(a, 127) + 128 * neg
                        if not any_pos:
                            raise Damage("empty quad")
                    if not any_quad:
                        raise Damage("empty block")
            if not any_block:
                raise Damage("empty line")
        prev_state, prev_f, prev_g, prev_F = state, f, g, F
    d.end_check()
    return out


def wavelet_like(rng, L, W, lines, density):
    v = np.zeros((lines, L), dtype=np.int64)
    x = np.arange(L) % W
    y = np.arange(L) // W
    near = 1.0 / (1.0 + 0.2 * np.maximum(x, y))
    for t in range(lines):
        hit = rng.random(L) < density * 4 * near
        if t > 0:
            hit |= (v[t - 1] != 0) & (rng.random(L) < 0.5)
        m = 1 + (rng.random(L) * rng.random(L) * 30 * near * 4).astype(np.int64)
        v[t] = np.where(hit, np.where(rng.random(L) < 0.5, -m, m), 0)
    return v.ravel()


def main():
    rng = np.random.default_rng(2026)
    cases = []
    # (name, L, W, values)
    cases.append(("wavelet 16x16, 12 lines", 256, 16, wavelet_like(rng, 256, 16, 12, 0.04)))
    cases.append(("L not a multiple of W", 50, 7, wavelet_like(rng, 50, 7, 9, 0.1)))
    v = np.zeros(3 * 40, dtype=np.int64)
    v[[0, 5, 47, 119]] = [-(2**31), 2**31 - 1, -(2**31 - 1), 1]
    cases.append(("extremes, W = 1", 40, 1, v))
    cases.append(("W = L, dense", 20, 20, rng.integers(-70000, 70000, size=100)))
    cases.append(("one element", 1, 1, np.array([-5])))
    cases.append(("empty lines between", 24, 6, np.concatenate([np.zeros(48, np.int64), wavelet_like(rng, 24, 6, 2, 0.2), np.zeros(24, np.int64)])))
    failures = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, L, W, vals in cases:
            src, dst = os.path.join(tmp, "in"), os.path.join(tmp, "out")
            vals.astype("<i4").tofile(src)
            subprocess.run([HELPER, str(L), str(W), src, dst], check=True)
            payload = open(dst, "rb").read()
            try:
                got = decode(payload, len(vals), L)
            except Damage as e:
                failures.append(f"{name}: decoding failed ({e})")
                continue
            if got != [int(x) for x in vals]:
                bad = [i for i, (a, b) in enumerate(zip(got, vals)) if a != b]
                failures.append(f"{name}: {len(bad)} elements differ, first at {bad[0]}: {got[bad[0]]} != {vals[bad[0]]}")
                continue
            for damaged, what in ((payload[:-1], "truncated"), (payload + b"\0", "a trailing byte")):
                try:
                    decode(damaged, len(vals), L)
                    failures.append(f"{name}: {what} payload decoded")
                except Damage:
                    pass
            print(f"ok  {name}: {len(vals)} elements, {int(np.count_nonzero(vals))} nonzero, {len(payload)} bytes")
    if failures:
        print("\n".join("FAIL " + f for f in failures))
        sys.exit(1)


if __name__ == "__main__":
    main()
