#!/usr/bin/env python3
"""Checks voxlat's Chitubox .ctb files with a decoder written from shared/reference/ctb-format.md
alone (no code shared with the writer): the header and its sections at the offsets it names, the
layer table and each LayerDefEx, the XOR cipher (against the reference's test vectors first), every
layer's RLE7 decoding to exactly width x height pixels and equal to the PNG folder the same recipe
gives (at the format's 7 bits), the RLE15 previews, for versions 2 to 5; and the bit-plane variant
(.cbddlp version 2, .photon version 1: magic 0x12FD0019, no key, no SlicerInfo, one table entry per
layer and plane, RLE1 planes whose grey is the nearest of the planes' levels). Also: the issue's command
line (`--printer saturn4 -o part.ctb`) writes a real .ctb, an extension that names no format is
refused before any work, and a bad `ctb_version:` is refused with the profile's file:line.
(The plain .ctb has no checksum; its integrity is the exact pixel count of every layer.)

usage: check_ctb.py VOXLAT_BINARY
"""
import hashlib
import os
import struct
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from check_goo import read_png  # noqa: E402  (the PNG reader of the .goo check: no writer code)

RECIPE = """domain: {box: [[0, 0, 0], [24, 18, 0.5]]}
fields:
  lattice: {tpms: gyroid, cell: 6, solid: sheet, level: 0.5}
result: lattice
outputs: {slices: {printer: PRINTER, layer: 0.05, file: FILE}}
"""
DISCLAIMER = (b"Layout and record format for the ctb and cbddlp file types are the copyrighted programs or codes "
              b"of CBD Technology (China) Inc..The Customer or User shall not in any manner reproduce, distribute, "
              b"modify, decompile, disassemble, decrypt, extract, reverse engineer, lease, assign, or sublicense "
              b"the said programs or codes.")

failures = []


def check(condition, message):
    if not condition:
        failures.append(message)
        print("FAIL:", message)


def u32(b, off):
    return struct.unpack_from("<I", b, off)[0]


def f32(b, off):
    return struct.unpack_from("<f", b, off)[0]


def keystream(key, index, n):
    """§6: the per-layer XOR bytes."""
    m = 0xFFFFFFFF
    c = (key * 0x2D83CDAC + 0xD8A83423) & m
    x = ((index * 0x1E1530CD + 0xEC3D47CD) & m) * c & m
    out = bytearray()
    while len(out) < n:
        out += struct.pack("<I", x)
        x = (x + c) & m
    return bytes(out[:n])


def decipher(data, key, index):
    if key == 0:
        return data
    return (np.frombuffer(data, np.uint8) ^ np.frombuffer(keystream(key, index, len(data)), np.uint8)).tobytes()


def decode_rle7(data, width, height):
    """§5.1: value byte (bit 7 = a length follows, big-endian, 1-4 bytes), decoded to 8 bits."""
    values, lengths = [], []
    k, n = 0, len(data)
    while k < n:
        b = data[k]
        k += 1
        v = b & 0x7F
        run = 1
        if b & 0x80:
            L = data[k]
            k += 1
            if L & 0x80 == 0:
                run = L
            elif L & 0xC0 == 0x80:
                run = ((L & 0x3F) << 8) | data[k]
                k += 1
            elif L & 0xE0 == 0xC0:
                run = ((L & 0x1F) << 16) | (data[k] << 8) | data[k + 1]
                k += 2
            elif L & 0xF0 == 0xE0:
                run = ((L & 0x0F) << 24) | (data[k] << 16) | (data[k + 1] << 8) | data[k + 2]
                k += 3
            else:
                check(False, "a length byte starting 1111 is invalid")
                return None
            check(run >= 2, "a flagged run is longer than 1")
        values.append(0 if v == 0 else (v << 1) | 1)
        lengths.append(run)
    total = sum(lengths)
    check(total == width * height, f"a layer decodes to {total} pixels, not {width} x {height}")
    if total != width * height:
        return None
    return np.repeat(np.array(values, np.uint8), lengths).reshape(height, width)


def decode_rle15(data, width, height):
    """§3.2: u16 words, bit 5 = a repeat word follows (bits 11-0: extra copies)."""
    words = struct.unpack(f"<{len(data) // 2}H", data)
    count, k = 0, 0
    while k < len(words):
        w = words[k]
        k += 1
        if w & 0x20:
            count += 1 + (words[k] & 0x0FFF)
            k += 1
        else:
            count += 1
    return count == width * height


AES_KEY = bytes.fromhex("D05B8E3371DE3D1AE54F22DDDF5BFD94AB5D643A9D7EBFAF4203F310D8522AEA")
AES_IV = bytes.fromhex("0F010A05050B060708060A0C0C0D090F")


def aes_cbc(data, decrypt=False):
    """§7: AES-256-CBC, no padding, from the published IV (python3-cryptography, else openssl)."""
    try:
        from cryptography.hazmat.primitives.ciphers import Cipher, algorithms, modes
        c = Cipher(algorithms.AES(AES_KEY), modes.CBC(AES_IV))
        op = c.decryptor() if decrypt else c.encryptor()
        return op.update(data) + op.finalize()
    except ImportError:
        run = subprocess.run(["openssl", "enc", "-d" if decrypt else "-e", "-aes-256-cbc", "-K", AES_KEY.hex(), "-iv",
                              AES_IV.hex(), "-nopad"], input=data, capture_output=True, check=True)
        return run.stdout


def signature_of(checksum):
    return aes_cbc(hashlib.sha256(struct.pack("<Q", checksum)).digest())


def check_cipher_vectors():
    check(aes_cbc(bytes(16)).hex() == "fdef75459601828a4b0e88f22dcc56e8", "AES-CBC test vector of the reference")
    check(signature_of(0).hex() == "1e9c9a1e7689201ecf60bbe265f7e84087e9cfb56565023913d35ee71acf87dc",
          "signature of checksum 0")
    check(signature_of(0xCAFEBABE).hex() == "05a372416adc7b35cd508ab10ac36bc451e640ed11760220be73bf8d962caed6",
          "signature of checksum 0xCAFEBABE")
    check(keystream(0x12345678, 0, 12).hex() == "27c5d1ceea294a23ad8ec277", "layer 0 keystream of the reference")
    check(keystream(0x12345678, 1, 12).hex() == "4e051e24116a9678d4ce0ecd", "layer 1 keystream of the reference")


PNG_FOLDERS = {}


def slice_pair(voxlat, tmp, printer, name, ext="ctb"):
    """The archive, and the PNG folder of the same recipe (one per display: the saturn-v* profiles,
    copies of elegoo-saturn's, share elegoo-saturn's)."""
    recipe = os.path.join(tmp, f"{name}-recipe.yaml")
    open(recipe, "w").write(RECIPE.replace("PRINTER", printer).replace("FILE", f"part.{ext}"))
    ctb = os.path.join(tmp, f"{name}.{ext}")
    display = name.split("-v")[0]
    runs = [["-o", ctb]]
    if display not in PNG_FOLDERS:
        PNG_FOLDERS[display] = os.path.join(tmp, f"{name}-png")
        runs.append(["--format", "png", "--preview", "off", "-o", PNG_FOLDERS[display]])
    for args in runs:
        run = subprocess.run([voxlat, "-q", "slice", recipe] + args, capture_output=True, text=True)
        check(run.returncode == 0, f"voxlat slice {printer} {args}: {run.stderr}")
        if run.returncode:
            return None, None
    return ctb, PNG_FOLDERS[display]


def check_encrypted(b, folder, name, version, expect):
    """§7: header, AES settings, previews, name, disclaimer, pointers, 88-byte records, signature."""
    magic, settings_size, settings_off, _, ver, sig_size, sig_off = struct.unpack_from("<7I", b, 0)
    check(magic == 0x12FD0107 and ver == version, f"{name}: magic {magic:#x}, version {ver}")
    check(settings_size == 288 and settings_off == 48 and sig_size == 32, f"{name}: settings and signature sizes")
    check(struct.unpack_from("<HHIII", b, 0x20) == (1, 1, 0, 42, 0), f"{name}: the header's fixed words")
    st = aes_cbc(b[48:48 + 288], decrypt=True)
    checksum = struct.unpack_from("<Q", st, 0)[0]
    check(b[sig_off:sig_off + 32] == signature_of(checksum), f"{name}: the signature matches the settings' checksum")
    if version >= 5:
        check(b[sig_off - 8:sig_off] == bytes.fromhex("FA52204200000000") and b[sig_off + 32:] == bytes.fromhex(
            "B332426D"), f"{name}: v5's bytes around the signature")
    else:
        check(sig_off + 32 == len(b), f"{name}: the signature ends the file")
    h = {"width_mm": f32(st, 0x0C), "height_mm": f32(st, 0x10), "machine_z": f32(st, 0x14),
         "total_mm": f32(st, 0x20), "layer_mm": f32(st, 0x24), "exposure": f32(st, 0x28),
         "bottom_exposure": f32(st, 0x2C), "bottom_layers": u32(st, 0x34), "res_x": u32(st, 0x38),
         "res_y": u32(st, 0x3C), "layers": u32(st, 0x40), "pwm": struct.unpack_from("<H", st, 0x7C)[0],
         "key": u32(st, 0x80)}
    for key, value in expect.items():
        check(abs(h[key] - value) < 1e-4 if isinstance(value, float) else h[key] == value,
              f"{name}: settings {key} = {h[key]}, expected {value}")
    N, W, H = h["layers"], h["res_x"], h["res_y"]
    check(N == 10 and h["key"] != 0, f"{name}: 10 layers, a non-zero key")
    check(u32(st, 0xF4) == N - 1 and u32(st, 0x10C) == 320, f"{name}: last layer index, disclaimer length")
    d_off = u32(st, 0x108)
    check(b[d_off:d_off + 320] == DISCLAIMER, f"{name}: the disclaimer")
    m_off, m_len = u32(st, 0xA0), u32(st, 0xA4)
    check(b[m_off:m_off + m_len].decode() == expect_name_enc[name], f"{name}: machine name")
    for off, size in ((u32(st, 0x44), (400, 300)), (u32(st, 0x48), (200, 125))):
        pw, ph, data_off, data_len = struct.unpack_from("<4I", b, off)
        check((pw, ph) == size and data_off == off + 16, f"{name}: preview header at {off}")
        check(decode_rle15(b[data_off:data_off + data_len], pw, ph), f"{name}: preview {size} covers its pixels")
    table = u32(st, 0x08)
    for i in range(N):
        record, page, size, zero = struct.unpack_from("<4I", b, table + 16 * i)
        check(page == 0 and size == 88 and zero == 0, f"{name}: layer {i} pointer")
        rsize, z, exposure, _off, data_off, page2, data_len, _, win_off, win_len = struct.unpack_from(
            "<IfffIIIIII", b, record)
        check(rsize == 88 and data_off == record + 88 and win_len == 0, f"{name}: layer {i} record")
        check(abs(z - (i + 1) * 0.05) < 1e-5, f"{name}: layer {i} Z {z}")
        bottom = i < h["bottom_layers"]
        check(abs(exposure - (h["bottom_exposure"] if bottom else h["exposure"])) < 1e-5, f"{name}: layer {i} exposure")
        image = decode_rle7(decipher(b[data_off:data_off + data_len], h["key"], i), W, H)
        png = read_png(os.path.join(folder, f"{i:05d}.png"))
        if image is not None:
            expected = np.where(png >> 1 == 0, 0, png | 1).astype(np.uint8)
            check(np.array_equal(expected, image), f"{name}: layer {i}: .ctb pixels differ from the PNG folder's")
    print(f"{name}: encrypted v{version}, {N} layers of {W} x {H} decoded, signature checked, {len(b)} bytes")


expect_name_enc = {}


def check_archive(voxlat, tmp, printer, name, version, expect, encrypted=False):
    ctb, folder = slice_pair(voxlat, tmp, printer, name)
    if not ctb:
        return
    b = open(ctb, "rb").read()
    if encrypted:
        expect_name_enc[name] = expect_name[printer]
        return check_encrypted(b, folder, name, version, expect)
    magic, ver = u32(b, 0), u32(b, 4)
    check(magic == (0x12FD0106 if version >= 4 else 0x12FD0086), f"{name}: magic {magic:#x}")
    check(ver == version, f"{name}: version {ver}")
    h = {"width_mm": f32(b, 0x08), "height_mm": f32(b, 0x0C), "machine_z": f32(b, 0x10),
         "total_mm": f32(b, 0x1C), "layer_mm": f32(b, 0x20), "exposure": f32(b, 0x24),
         "bottom_exposure": f32(b, 0x28), "bottom_layers": u32(b, 0x30), "res_x": u32(b, 0x34),
         "res_y": u32(b, 0x38), "layers": u32(b, 0x44), "planes": u32(b, 0x5C),
         "pwm": struct.unpack_from("<H", b, 0x60)[0], "key": u32(b, 0x64)}
    for key, value in expect.items():
        check(abs(h[key] - value) < 1e-4 if isinstance(value, float) else h[key] == value,
              f"{name}: header {key} = {h[key]}, expected {value}")
    N, W, H = h["layers"], h["res_x"], h["res_y"]
    check(N == 10, f"{name}: 10 layers of 0.05 mm in 0.5 mm, header says {N}")
    check(abs(h["layer_mm"] - 0.05) < 1e-7 and abs(h["total_mm"] - N * 0.05) < 1e-4, f"{name}: heights")
    check(h["planes"] == 1 and h["key"] != 0, f"{name}: one plane, a non-zero key (firmware refuses 0)")
    # Previews: header, data right after it, RLE15 covering exactly width x height.
    for off, size in ((u32(b, 0x3C), (400, 300)), (u32(b, 0x48), (200, 125))):
        pw, ph, data_off, data_len = struct.unpack_from("<4I", b, off)
        check((pw, ph) == size and data_off == off + 32, f"{name}: preview header at {off}")
        check(decode_rle15(b[data_off:data_off + data_len], pw, ph), f"{name}: preview {size} covers its pixels")
    # PrintParameters and SlicerInfo.
    pp, pp_size = u32(b, 0x54), u32(b, 0x58)
    check(pp_size == 60 and u32(b, pp + 0x28) == h["bottom_layers"], f"{name}: PrintParameters")
    si, si_size = u32(b, 0x68), u32(b, 0x6C)
    check(si_size == 76, f"{name}: SlicerInfo size")
    name_off, name_len = u32(b, si + 0x1C), u32(b, si + 0x20)
    check(name_off == si + 76 and b[name_off:name_off + name_len].decode() == expect_name[printer],
          f"{name}: machine name `{b[name_off:name_off + name_len]}`")
    v4 = u32(b, si + 0x40)
    if version >= 4:
        check(u32(b, v4 + 0x34) == N - 1, f"{name}: PrintParametersV4 last layer index")
        d_off, d_len = u32(b, v4 + 0x48), u32(b, v4 + 0x4C)
        check(d_len == 320 and b[d_off:d_off + d_len] == DISCLAIMER, f"{name}: the disclaimer")
        check(f32(b, v4 + 0x0C) == 4.0 and f32(b, v4 + 0x14) == 4.0, f"{name}: the two 4.0 of V4")
        resin = u32(b, v4 + 0x50)
        if version >= 5:
            m_off, m_len = u32(b, resin + 0x08), u32(b, resin + 0x1C)
            check(resin > 0 and b[m_off:m_off + m_len].decode() == expect_name[printer], f"{name}: ResinParameters")
        else:
            check(resin == 0, f"{name}: no ResinParameters before v5")
    else:
        check(v4 == 0, f"{name}: no PrintParametersV4 before v4")
    # The layer table and the layers.
    table = u32(b, 0x40)
    end = 0
    for i in range(N):
        e = table + 36 * i
        z, exposure, _off, data_off, data_len, page, record = struct.unpack_from("<fffIIII", b, e)
        check(abs(z - (i + 1) * 0.05) < 1e-5, f"{name}: layer {i} Z {z}")
        bottom = i < h["bottom_layers"]
        check(abs(exposure - (h["bottom_exposure"] if bottom else h["exposure"])) < 1e-5, f"{name}: layer {i} exposure")
        check(page == 0, f"{name}: layer {i} page")
        if version >= 3:
            check(record == 84, f"{name}: layer {i} record size {record}")
            ex = data_off - 84
            check(b[ex:ex + 36] == b[e:e + 36], f"{name}: layer {i}: LayerDefEx copies its table entry")
            check(u32(b, ex + 36) == 84 + data_len, f"{name}: layer {i}: LayerDefEx total size")
            check(f32(b, ex + 0x50) == 255.0, f"{name}: layer {i}: light PWM")
        end = max(end, data_off + data_len)
        image = decode_rle7(decipher(b[data_off:data_off + data_len], h["key"], i), W, H)
        png = read_png(os.path.join(folder, f"{i:05d}.png"))
        if image is not None:
            # The format keeps 7 bits: grey g is stored as g >> 1 and read as 0, or (g >> 1) << 1 | 1.
            expected = np.where(png >> 1 == 0, 0, png | 1).astype(np.uint8)
            check(png.shape == image.shape and np.array_equal(expected, image),
                  f"{name}: layer {i}: .ctb pixels differ from the PNG folder's")
    check(end == len(b), f"{name}: the file ends with the last layer ({end} of {len(b)} bytes)")
    print(f"{name}: v{version}, {N} layers of {W} x {H} decoded, {len(b)} bytes")


def decode_rle1(data, width, height):
    """§5.2: one byte a run, bit 7 = on, bits 6-0 = 1 to 125 pixels; exactly one bilevel image."""
    data = np.frombuffer(data, np.uint8)
    counts = (data & 0x7F).astype(np.int64)
    check(bool(np.all(counts > 0)) and bool(np.all(counts <= 125)), "RLE1 runs of 1 to 125 pixels")
    total = int(counts.sum())
    check(total == width * height, f"an RLE1 plane decodes to {total} pixels, not {width} x {height}")
    if total != width * height:
        return None
    return np.repeat((data >> 7).astype(np.int32), counts).reshape(height, width)


def check_bit_planes(voxlat, tmp, printer, name, ext, version, expect):
    """The bit-plane variant (§1, §3, §4, §5.2): header, previews, PrintParameters (v2), no
    SlicerInfo, N x planes table entries (plane p of layer i at p·N + i), every plane decoded."""
    path, folder = slice_pair(voxlat, tmp, printer, name, ext)
    if not path:
        return
    b = open(path, "rb").read()
    check(u32(b, 0) == 0x12FD0019 and u32(b, 4) == version, f"{name}: magic {u32(b, 0):#x}, version {u32(b, 4)}")
    N, W, H, planes = u32(b, 0x44), u32(b, 0x34), u32(b, 0x38), u32(b, 0x5C)
    check((W, H) == (expect["res_x"], expect["res_y"]) and N == 10, f"{name}: {W} x {H}, {N} layers")
    check(planes == expect["planes"], f"{name}: {planes} planes, expected {expect['planes']}")
    check(u32(b, 0x64) == 0 and u32(b, 0x68) == 0, f"{name}: key 0 and no SlicerInfo")
    bottom_layers, exposure, bottom_exposure = u32(b, 0x30), f32(b, 0x24), f32(b, 0x28)
    check(abs(exposure - expect["exposure"]) < 1e-5 and abs(bottom_exposure - expect["bottom_exposure"]) < 1e-5,
          f"{name}: exposures {exposure}, {bottom_exposure}")
    pp, pp_size = u32(b, 0x54), u32(b, 0x58)
    if version >= 2:
        check(pp_size == 60 and u32(b, pp + 0x28) == bottom_layers, f"{name}: PrintParameters")
    else:
        check(pp == 0, f"{name}: version 1 has no PrintParameters")
    for off, size in ((u32(b, 0x3C), (400, 300)), (u32(b, 0x48), (200, 125))):
        pw, ph, data_off, data_len = struct.unpack_from("<4I", b, off)
        check((pw, ph) == size and data_off == off + 32, f"{name}: preview header at {off}")
        check(decode_rle15(b[data_off:data_off + data_len], pw, ph), f"{name}: preview {size} covers its pixels")
    table = u32(b, 0x40)
    levels = np.array([0] + [n * (256 // planes) - 1 for n in range(1, planes + 1)], np.int32)
    end = 0
    for i in range(N):
        on = np.zeros((H, W), np.int32)
        for p in range(planes):
            z, exp, _off, data_off, data_len, page, _record = struct.unpack_from("<fffIIII", b, table + 36 * (p * N + i))
            check(abs(z - (i + 1) * 0.05) < 1e-5 and page == 0, f"{name}: layer {i} plane {p}: Z {z}")
            check(abs(exp - (bottom_exposure if i < bottom_layers else exposure)) < 1e-5,
                  f"{name}: layer {i} plane {p}: exposure")
            end = max(end, data_off + data_len)
            plane = decode_rle1(b[data_off:data_off + data_len], W, H)
            if plane is None:
                return
            on += plane
        image = np.where(on == 0, 0, on * (256 // planes) - 1)
        png = read_png(os.path.join(folder, f"{i:05d}.png")).astype(np.int32)
        # Each pixel at the planes' level nearest its grey (ties either way).
        best = np.abs(png[..., None] - levels).min(axis=-1)
        check(png.shape == image.shape and np.array_equal(np.abs(png - image), best),
              f"{name}: layer {i}: pixels are not the nearest levels to the PNG folder's")
    check(end == len(b), f"{name}: the file ends with the last plane ({end} of {len(b)} bytes)")
    print(f"{name}: .{ext} v{version}, {N} layers x {planes} planes of {W} x {H} decoded, {len(b)} bytes")


expect_name = {"elegoo-saturn": "ELEGOO SATURN", "mars2-pro": "ELEGOO Mars 2 Pro", "saturn4": "ELEGOO Saturn 4",
               "mars3": "ELEGOO Mars 3"}


def versioned_profile(tmp, version, encrypted=False):
    """elegoo-saturn's profile with another ctb_version, as a file of the user's."""
    source = os.path.join(os.path.dirname(__file__), "..", "..", "data", "printers", "elegoo-saturn.yaml")
    text = open(source).read().replace("ctb_version: 4", f"ctb_version: {version}" +
                                       ("\nctb_encrypted: true" if encrypted else ""))
    path = os.path.join(tmp, f"saturn-v{version}{'e' if encrypted else ''}.yaml")
    open(path, "w").write(text)
    expect_name[path] = "ELEGOO SATURN"
    return path


def check_refusals(voxlat, tmp):
    recipe = os.path.join(tmp, "refuse.yaml")
    open(recipe, "w").write(RECIPE.replace("PRINTER", "saturn4").replace("FILE", "part.ctb"))
    # An extension that names no format: exit 2 before any work, nothing written.
    out = os.path.join(tmp, "part.xyz")
    run = subprocess.run([voxlat, "-q", "slice", recipe, "--printer", "saturn4", "-o", out], capture_output=True,
                         text=True)
    check(run.returncode == 2, f"-o part.xyz: exit {run.returncode}")
    check("`.xyz`" in run.stderr and ".ctb" in run.stderr, f"-o part.xyz: the message says why: {run.stderr}")
    check(not os.path.exists(out), "-o part.xyz: nothing written")
    # The same in a recipe's `file:`, with the recipe's line.
    bad = os.path.join(tmp, "bad-ext.yaml")
    open(bad, "w").write(RECIPE.replace("PRINTER", "saturn4").replace("FILE", "part.xyz"))
    run = subprocess.run([voxlat, "-q", "run", bad, "--out", os.path.join(tmp, "bad-out")], capture_output=True,
                         text=True)
    check(run.returncode == 2 and "bad-ext.yaml:5" in run.stderr, f"file: part.xyz refused at its line: {run.stderr}")
    check(not os.path.exists(os.path.join(tmp, "bad-out", "part.xyz")), "file: part.xyz: nothing written")
    # A bad ctb_version names the profile's file and line.
    profile = versioned_profile(tmp, 7)
    run = subprocess.run([voxlat, "-q", "slice", recipe, "--printer", profile, "-o", os.path.join(tmp, "v7.ctb")],
                         capture_output=True, text=True)
    check(run.returncode == 2 and "saturn-v7.yaml:10" in run.stderr, f"ctb_version: 7 refused: {run.stderr}")
    check(not os.path.exists(os.path.join(tmp, "v7.ctb")), "ctb_version: 7: nothing written")
    # The encrypted layout before version 4 likewise.
    profile = versioned_profile(tmp, 3, True)
    run = subprocess.run([voxlat, "-q", "slice", recipe, "--printer", profile, "-o", os.path.join(tmp, "v3e.ctb")],
                         capture_output=True, text=True)
    check(run.returncode == 2 and "saturn-v3e.yaml:11" in run.stderr, f"ctb_encrypted on v3 refused: {run.stderr}")
    check(not os.path.exists(os.path.join(tmp, "v3e.ctb")), "ctb_encrypted on v3: nothing written")


def main():
    voxlat = sys.argv[1]
    check_cipher_vectors()
    with tempfile.TemporaryDirectory() as tmp:
        saturn = {"res_x": 3840, "res_y": 2400, "width_mm": 192.0, "height_mm": 120.0, "machine_z": 200.0,
                  "bottom_layers": 4, "exposure": 2.5, "bottom_exposure": 30.0, "pwm": 255}
        check_archive(voxlat, tmp, "elegoo-saturn", "saturn", 4, saturn)
        for version in (2, 3, 5):
            check_archive(voxlat, tmp, versioned_profile(tmp, version), f"saturn-v{version}", version, saturn)
        for version in (4, 5):
            check_archive(voxlat, tmp, versioned_profile(tmp, version, True), f"saturn-v{version}e", version, saturn,
                          encrypted=True)
        check_archive(voxlat, tmp, "mars2-pro", "mars2-pro", 4,
                      {"res_x": 1620, "res_y": 2560, "width_mm": 82.62, "height_mm": 130.56, "machine_z": 160.0})
        check_archive(voxlat, tmp, "mars3", "mars3", 4,
                      {"res_x": 4098, "res_y": 2560, "width_mm": 143.43, "height_mm": 89.6, "machine_z": 175.0},
                      encrypted=True)
        # The command line: a Saturn 4 (a .goo printer) asked for part.ctb gets a .ctb.
        check_archive(voxlat, tmp, "saturn4", "saturn4", 4,
                      {"res_x": 11520, "res_y": 5120, "width_mm": 218.88, "height_mm": 122.88})
        # The bit-plane variant, anti-aliasing on (the recipe's default: 4 planes) and off (1).
        old_rgb = {"res_x": 1440, "res_y": 2560, "exposure": 8.0, "bottom_exposure": 60.0}
        check_bit_planes(voxlat, tmp, "epax-x1", "epax-x1", "cbddlp", 2, dict(old_rgb, planes=4))
        global RECIPE
        RECIPE = RECIPE.replace("file: FILE", "file: FILE, aa: off")
        check_bit_planes(voxlat, tmp, "anycubic-photon", "anycubic-photon", "photon", 1, dict(old_rgb, planes=1))
        check_refusals(voxlat, tmp)
    if failures:
        print(f"{len(failures)} check(s) failed")
        return 1
    print("ctb files: all checks passed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
