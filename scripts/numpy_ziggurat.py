"""Take numpy's ziggurat tables for float64 normals out of a numpy wheel, for the hand tasks.

    numpy_ziggurat.py WHEEL OUT

`Generator.normal` draws with a 256-layer ziggurat whose tables (`ki_double`, `wi_double`,
`fi_double`) numpy ships as constants. Recomputing them from their defining recurrence does not
give numpy's bits (they were computed once, with some other libm), and the hand environments'
resets must draw exactly numpy's normals. So, as the MuJoCo library and the model files come
from their wheels, the tables come from numpy's: the wheel carries `numpy/random/lib/
libnpyrandom.a`, and the object inside it that holds `random_standard_normal` has the three
tables as symbols. We read them with the standard library alone (zip, ar, ELF64) and write
OUT: 256 u64 (ki), then 256 f64 (wi), then 256 f64 (fi), little endian, 6144 bytes.
"""

import struct
import sys
import zipfile

TABLES = ("ki_double", "wi_double", "fi_double")
SIZE = 256 * 8


def ar_members(blob):
    if not blob.startswith(b"!<arch>\n"):
        raise SystemExit("libnpyrandom.a is not an ar archive")
    pos, names = 8, b""
    while pos + 60 <= len(blob):
        header = blob[pos:pos + 60]
        name, size = header[:16].decode().strip(), int(header[48:58].decode().strip())
        body = blob[pos + 60:pos + 60 + size]
        if name == "//":
            names = body
        elif name.startswith("/") and name[1:].isdigit():
            off = int(name[1:])
            name = names[off:names.index(b"/\n", off)].decode()
        yield name.rstrip("/"), body
        pos += 60 + size + (size & 1)


def elf_symbols(obj):
    if obj[:4] != b"\x7fELF" or obj[4] != 2 or obj[5] != 1:
        return {}
    shoff, = struct.unpack_from("<Q", obj, 0x28)
    shentsize, shnum = struct.unpack_from("<HH", obj, 0x3A)
    sections = [struct.unpack_from("<IIQQQQIIQQ", obj, shoff + i * shentsize) for i in range(shnum)]
    found = {}
    for sh in sections:
        if sh[1] != 2:  # SHT_SYMTAB
            continue
        strtab = sections[sh[6]]
        for k in range(sh[5] // sh[9]):
            st_name, _, _, st_shndx, st_value, st_size = struct.unpack_from("<IBBHQQ", obj, sh[4] + k * sh[9])
            end = obj.index(b"\0", strtab[4] + st_name)
            name = obj[strtab[4] + st_name:end].decode()
            if name in TABLES and st_size == SIZE:
                start = sections[st_shndx][4] + st_value
                found[name] = obj[start:start + SIZE]
    return found


def main():
    wheel, out = sys.argv[1], sys.argv[2]
    lib = zipfile.ZipFile(wheel).read("numpy/random/lib/libnpyrandom.a")
    for _, body in ar_members(lib):
        found = elf_symbols(body)
        if len(found) == len(TABLES):
            data = b"".join(found[t] for t in TABLES)
            ki = struct.unpack("<256Q", data[:SIZE])
            wi = struct.unpack("<256d", data[SIZE:2 * SIZE])
            # Sanity: the layers widen towards the tail and ki[1] = 0 (the top layer always rejects).
            if ki[1] != 0 or not all(wi[i] < wi[i + 1] for i in range(1, 255)):
                raise SystemExit("the tables found do not look like numpy's ziggurat")
            with open(out, "wb") as f:
                f.write(data)
            return
    raise SystemExit(f"{wheel}: no object in numpy/random/lib/libnpyrandom.a holds {', '.join(TABLES)}")


if __name__ == "__main__":
    main()
