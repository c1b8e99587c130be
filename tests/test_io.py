import numpy as np
import pytest
import torch

from prismstereo.io import ImageIOError, read_image, write_image


@pytest.mark.parametrize("channels", [1, 3])
@pytest.mark.parametrize("bits", [8, 16])
def test_round_trip(tmp_path, channels, bits):
    gen = torch.Generator().manual_seed(0)
    img = torch.rand(channels, 12, 17, generator=gen)
    levels = 2**bits - 1
    img = torch.round(img * levels) / levels
    path = tmp_path / f"img{bits}.png"
    write_image(path, img, bits)
    back = read_image(path)
    assert back.shape == img.shape and back.dtype == torch.float32
    torch.testing.assert_close(back, img, atol=1e-7, rtol=0)


def test_rgb_order(tmp_path):
    img = torch.zeros(3, 2, 2)
    img[0] = 1.0  # red
    write_image(tmp_path / "red.png", img)
    import cv2

    bgr = cv2.imread(str(tmp_path / "red.png"))
    assert bgr[0, 0].tolist() == [0, 0, 255]
    assert read_image(tmp_path / "red.png")[:, 0, 0].tolist() == [1.0, 0.0, 0.0]


def test_errors(tmp_path):
    with pytest.raises(ImageIOError, match="image not found"):
        read_image(tmp_path / "missing.png")
    (tmp_path / "junk.png").write_bytes(b"not an image")
    with pytest.raises(ImageIOError, match="cannot decode"):
        read_image(tmp_path / "junk.png")
    with pytest.raises(ImageIOError, match="need bits 8 or 16"):
        write_image(tmp_path / "x.png", torch.zeros(1, 4, 4), bits=12)
    import cv2

    cv2.imwrite(str(tmp_path / "float.tiff"), np.zeros((4, 4), np.float32))
    with pytest.raises(ImageIOError, match="unsupported image depth"):
        read_image(tmp_path / "float.tiff")
