#!/usr/bin/env python3
"""docs/bench/realphoto.png: truth | the authors' method (our port, peer.py) | polnlos.

Usage: python3 figure.py PEER_OUT_DIR POLNLOS_OUT_DIR OUT.png
(PEER_OUT_DIR from `peer.py --out`, POLNLOS_OUT_DIR from `polnlos reconstruct --photo`).
Shown with the monitor's top up: polnlos's scene rows run bottom-up (docs/realphoto.md).
"""
import pathlib
import sys

import numpy as np
from PIL import Image

HERE = pathlib.Path(__file__).resolve().parent
peer, ours, out = map(pathlib.Path, sys.argv[1:4])
truth = np.load(HERE.parent.parent / "tests/data/saunders-chair/truth_rgb.npy") / 255.0
authors = np.clip(np.load(peer / "authors.npy"), 0, 255) / 255.0
mine = np.load(ours / "recovered.npy")  # top row first, as the truth
gap = np.ones((29, 2, 3))
row = np.concatenate([truth, gap, authors, gap, mine], axis=1)
Image.fromarray((row * 255).round().astype(np.uint8)).resize((row.shape[1] * 8, 29 * 8), Image.NEAREST).save(out)
