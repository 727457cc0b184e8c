"""Corrupt a snapshot piece in the ways a disk, a copy or a hand can, for tests/helpers/snap_check.sh
(mode corrupt).

    snap_corrupt.py bytes PIECE DATASET   random bytes over the stored data of DATASET
    snap_corrupt.py scale PIECE DATASET   DATASET *= 1.001 (checksum left as it was)
    snap_corrupt.py nan   PIECE DATASET   one element NaN, checksum recomputed (so only the
                                          finiteness check can catch it)
    snap_corrupt.py shift PIECE DATASET K every element of an integer DATASET plus K, checksum
                                          recomputed (so only the range checks can catch it)
The dataset must hold data (an empty one makes this script fail, never a silent no-op).
"""
import os
import sys

import h5py
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "scripts"))
import crowdrom_io  # noqa: E402


def main():
    mode, path, name = sys.argv[1:4]
    if mode == "shift":
        with h5py.File(path, "r+") as f:
            d = f[name]
            if d.size == 0 or d.dtype.kind not in "iu":
                sys.exit(f"snap_corrupt: '{name}' in '{path}' is empty or not integer")
            a = d[...] + int(sys.argv[4])
            d[...] = a
            d.attrs["checksum"] = np.bytes_(crowdrom_io.digest(d[...]))
        return
    if mode == "bytes":
        with h5py.File(path, "r") as f:
            d = f[name]
            off, nbytes = d.id.get_offset(), d.id.get_storage_size()
        if off is None or nbytes < 8:
            sys.exit(f"snap_corrupt: '{name}' in '{path}' has no contiguous data to overwrite")
        rng = np.random.default_rng(16)
        n = min(nbytes, 64)
        with open(path, "r+b") as fh:
            fh.seek(off + (nbytes - n) // 2)
            fh.write(rng.integers(0, 256, n, dtype=np.uint8).tobytes())
        return
    with h5py.File(path, "r+") as f:
        d = f[name]
        if d.size == 0:
            sys.exit(f"snap_corrupt: '{name}' in '{path}' is empty")
        a = d[...]
        if mode == "scale":
            d[...] = a * 1.001
        elif mode == "nan":
            flat = a.reshape(-1)
            flat[flat.size // 2] = np.nan
            d[...] = flat.reshape(a.shape)
            d.attrs["checksum"] = np.bytes_(crowdrom_io.digest(d[...]))
        else:
            sys.exit(f"snap_corrupt: unknown mode '{mode}'")


if __name__ == "__main__":
    main()
