"""Renders the test views of a capture with a PyTorch reference model that `dnr_torch.py train
--save` wrote, as 8-bit RGB PNG composited on white, named by their index in the capture's test
split, so that `dnr bench bake` measures them with the same metrics as its own assets.

Usage: python peer_render.py PEER_SCRIPT CAPTURE MODEL_PT OUT_DIR CACHE_DIR WIDTH
"""
import importlib.util
import os
import sys


def main():
    peer, capture, model_pt, out_dir, cache, width = sys.argv[1:7]
    sys.path.insert(0, os.path.dirname(os.path.abspath(peer)))
    spec = importlib.util.spec_from_file_location("dnr_torch", peer)
    P = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(P)
    import torch
    from PIL import Image

    views = P.prepare_views(capture, "test", 1.0, cache, verbose=False)
    # The reference's training defaults: 16 channels, 512x512, 4 levels.
    model = P.DNR(16, 512, 4, float(width))
    model.load_state_dict(torch.load(model_pt, map_location="cpu"))
    model.eval()
    os.makedirs(out_dir, exist_ok=True)
    for i, v in enumerate(views):
        Image.fromarray(P.render(model, v)).save(os.path.join(out_dir, f"{i:04d}.png"))


if __name__ == "__main__":
    main()
