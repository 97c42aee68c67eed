#!/usr/bin/env python3
"""Make codec test vectors with cantools, an independent DBC implementation.

Writes tests/data/codec_vectors.dbc (little/big endian, signed, odd positions and
sizes, factors and offsets) and tests/data/codec_vectors.json: for each message a
list of {values, data}, where data is what cantools encodes for values. The Rust
codec must decode data to values and encode values to data.
Run: python3 tools/make-codec-vectors.py
"""
import json
import pathlib
import random

import cantools

DBC = '''VERSION ""

NS_ :

BS_:

BU_: T

BO_ 256 LE_MIX: 8 T
 SG_ u3 : 0|3@1+ (1,0) [0|7] "" T
 SG_ s13 : 3|13@1- (0.01,0) [-40.96|40.95] "" T
 SG_ u14 : 16|14@1+ (0.03125,0) [0|511.96875] "" T
 SG_ s7 : 30|7@1- (0.5,-3) [-35|28.5] "" T
 SG_ u21 : 37|21@1+ (0.001,100) [100|2197.151] "" T
 SG_ s6 : 58|6@1- (1,0) [-32|31] "" T

BO_ 257 BE_MIX: 8 T
 SG_ b12 : 7|12@0+ (1,0) [0|4095] "" T
 SG_ bs10 : 11|10@0- (0.1,0) [-51.2|51.1] "" T
 SG_ b16 : 33|16@0+ (0.01,-100) [-100|555.35] "" T
 SG_ bs5 : 49|5@0- (1,0) [-16|15] "" T
 SG_ b9 : 28|9@0+ (2,1) [1|1023] "" T

BO_ 2147484160 EXT_SIGNED: 8 T
 SG_ big : 0|32@1- (0.0001,0) [-214748.3648|214748.3647] "" T
 SG_ tail : 39|24@0- (0.001,0) [-8388.608|8388.607] "" T
'''

def main():
    root = pathlib.Path(__file__).resolve().parent.parent
    (root / "tests/data/codec_vectors.dbc").write_text(DBC)
    db = cantools.database.load_string(DBC, strict=True)
    rng = random.Random(20231)
    out = {}
    for msg in db.messages:
        cases = []
        for k in range(40):
            values = {}
            for s in msg.signals:
                lo = s.minimum if s.minimum is not None else 0
                hi = s.maximum if s.maximum is not None else 1
                if k == 0:
                    v = lo
                elif k == 1:
                    v = hi
                else:
                    v = rng.uniform(lo, hi)
                # Snap to the signal's grid so decode is exact.
                raw = round((v - s.offset) / s.scale)
                values[s.name] = raw * s.scale + s.offset
            data = msg.encode(values, strict=True)
            decoded = msg.decode(data, decode_choices=False)
            cases.append({"values": {n: float(decoded[n]) for n in values}, "data": data.hex().upper()})
        out[msg.name] = cases
    (root / "tests/data/codec_vectors.json").write_text(json.dumps(out, indent=1) + "\n")

if __name__ == "__main__":
    main()
