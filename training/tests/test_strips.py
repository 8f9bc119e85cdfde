import os

import numpy as np
from PIL import Image

from ssr import strips as S
from ssr.data import frame_name, list_sequences, read_exr, write_exr


def test_strips_show_each_method_and_the_reference(dataset, tmp_path, capsys):
    seq = list_sequences(dataset, "test", None)[0]
    pred = str(tmp_path / "pred")
    for t in range(seq.frames):
        ref = read_exr(os.path.join(seq.path, frame_name(t)), ["reference.R", "reference.G", "reference.B"])
        for method, img in [("perfect", ref), ("dark", ref * 0.5)]:
            d = os.path.join(pred, method, "test", seq.name)
            os.makedirs(d, exist_ok=True)
            write_exr(os.path.join(d, frame_name(t)), {"pred": img.transpose(2, 0, 1)}, {"pred": ["R", "G", "B"]})
    out = str(tmp_path / "strips")
    assert S.main(["--data", dataset, "--pred", pred, "--out", out, "--methods", "perfect", "dark", "--scale", "3"]) == 0
    png = np.asarray(Image.open(os.path.join(out, f"{seq.scene}.png")))
    h, w = seq.height * 3, seq.width * 3
    assert png.shape == (h + S.LABEL_H + 2, 3 * w + 2 * 2, 3)
    body = png[S.LABEL_H + 2 :]
    perfect, dark, ref = body[:, :w], body[:, w + 2 : 2 * w + 2], body[:, 2 * w + 4 :]
    assert np.array_equal(perfect, ref), "the perfect prediction shows the reference"
    assert dark.astype(int).sum() < ref.astype(int).sum(), "the darker prediction looks darker"
    assert np.array_equal(ref[::3, ::3], ref[1::3, 1::3]), "pixel-for-pixel upscaling"
    assert "perfect | dark | reference" in capsys.readouterr().out
    # a missing method is a clear error naming the file
    assert S.main(["--data", dataset, "--pred", pred, "--out", out, "--methods", "nope"]) == 1
    assert "missing frame" in capsys.readouterr().err
