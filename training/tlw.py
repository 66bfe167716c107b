"""Writer and reader of terralign's weight container (.tlw), shared by the converter and the
parity-vector writer. Layout (little-endian), as read by src/nn/weights.cpp:

  8 bytes   magic "TLNNWGT\\0"
  u32       format version (1)
  u32       architecture text length, then the text (UTF-8)
  u32       tensor count; per tensor: u16 name length, name, u8 dtype (1 = float32),
            u8 rank, u32 x rank dims, u64 offset into the data block, u64 byte count
  u64       data block length, then the data (each tensor 16-byte aligned)
  u64       FNV-1a 64 of every byte before it
"""
import os
import struct

MAGIC = b"TLNNWGT\0"
VERSION = 1


def fnv1a64(data):
    h = 0xcbf29ce484222325
    for b in data:
        h ^= b
        h = (h * 0x100000001b3) & 0xFFFFFFFFFFFFFFFF
    return h


def write(path, arch, tensors):
    """tensors: list of (name, numpy float32 array)."""
    import numpy as np  # only the writer needs it: replace_architecture() runs on the stdlib
    head = bytearray(MAGIC)
    head += struct.pack("<I", VERSION)
    a = arch.encode()
    head += struct.pack("<I", len(a)) + a
    head += struct.pack("<I", len(tensors))
    blob = bytearray()
    for name, arr in tensors:
        arr = np.ascontiguousarray(arr, dtype="<f4")
        while len(blob) % 16:
            blob.append(0)
        n = name.encode()
        head += struct.pack("<H", len(n)) + n + struct.pack("<BB", 1, arr.ndim)
        head += struct.pack("<" + "I" * arr.ndim, *arr.shape)
        head += struct.pack("<QQ", len(blob), arr.nbytes)
        blob += arr.tobytes()
    body = bytes(head) + struct.pack("<Q", len(blob)) + bytes(blob)
    _write_atomic(path, body)


def _write_atomic(path, body):
    with open(path + ".tmp", "wb") as f:
        f.write(body + struct.pack("<Q", fnv1a64(body)))
    os.replace(path + ".tmp", path)


def architecture(path):
    """The architecture text of a weight file (after checking its magic and checksum)."""
    data = open(path, "rb").read()
    if data[:8] != MAGIC or struct.unpack_from("<Q", data, len(data) - 8)[0] != fnv1a64(data[:-8]):
        raise ValueError(f"{path}: not a terralign weight file, or its checksum does not match")
    (n,) = struct.unpack_from("<I", data, 12)
    return data[16:16 + n].decode(), data


def read(path):
    """The tensors of a weight file as {name: numpy float32 array} (e.g. to warm-start training
    from shipped weights: the names are the PyTorch state-dict keys export_deep.py wrote)."""
    import numpy as np
    arch, data = architecture(path)
    pos = 16 + len(arch.encode())
    (count,) = struct.unpack_from("<I", data, pos)
    pos += 4
    heads = []
    for _ in range(count):
        (n,) = struct.unpack_from("<H", data, pos)
        name = data[pos + 2:pos + 2 + n].decode()
        pos += 2 + n
        dtype, rank = struct.unpack_from("<BB", data, pos)
        if dtype != 1:
            raise ValueError(f"{path}: tensor {name} has dtype {dtype}, only 1 (float32) is known")
        dims = struct.unpack_from("<" + "I" * rank, data, pos + 2)
        off, size = struct.unpack_from("<QQ", data, pos + 2 + 4 * rank)
        pos += 2 + 4 * rank + 16
        heads.append((name, dims, off, size))
    base = pos + 8  # after the u64 data block length
    return {name: np.frombuffer(data, "<f4", size // 4, base + off).reshape(dims).copy()
            for name, dims, off, size in heads}


def replace_architecture(path, arch):
    """Rewrites a weight file with another architecture text (e.g. a new comment line); the
    tensors are kept byte for byte (their offsets count from the data block)."""
    old, data = architecture(path)
    a = arch.encode()
    body = data[:12] + struct.pack("<I", len(a)) + a + data[16 + len(old.encode()):-8]
    _write_atomic(path, body)
