import numpy as np
import pytest
import torch

from prismstereo.errors import ShapeError
from prismstereo.io import (
    ImageIOError,
    decode_image,
    depth_png_scale,
    read_depth,
    read_image,
    write_depth,
    write_depth_png,
    write_image,
)


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


def test_depth_png_round_trip_and_clipping(tmp_path):
    from prismstereo.io import read_depth_png, write_depth_npy, write_depth_png

    depth = torch.tensor([[100.0, 200.123, float("nan")], [255.99, 300.0, 0.001]], dtype=torch.float64)
    valid = torch.tensor([[True, True, True], [True, True, False]])
    assert write_depth_png(tmp_path / "d.png", depth, valid) == 1  # 300 mm > 65535 / 256 mm
    import cv2

    raw = cv2.imread(str(tmp_path / "d.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw.tolist() == [[25600, 51231, 0], [65533, 65535, 0]]
    back = read_depth_png(tmp_path / "d.png")
    assert torch.isnan(back[0, 2]) and torch.isnan(back[1, 2])
    assert abs(float(back[0, 1]) - 200.123) <= 1 / 512
    write_depth_png(tmp_path / "s.png", depth, valid, scale=32.0)
    assert float(read_depth_png(tmp_path / "s.png", scale=32.0)[1, 1]) == 300.0
    write_depth_npy(tmp_path / "d.npy", depth, valid)
    arr = np.load(tmp_path / "d.npy")
    assert arr.dtype == np.float32 and np.isnan(arr[[0, 1], [2, 2]]).all() and arr[1, 1] == 300.0
    with pytest.raises(ImageIOError, match="scale must be a positive number"):
        write_depth_png(tmp_path / "x.png", depth, scale=0.0)
    with pytest.raises(ImageIOError, match="not a single-channel 16-bit depth PNG"):
        write_image(tmp_path / "rgb.png", torch.zeros(3, 2, 2))
        read_depth_png(tmp_path / "rgb.png")


# ----------------------------------------------------------------------------- depth files in every format
def _depth_and_mask(deepest: float = 1300.0):
    g = torch.Generator().manual_seed(5)
    depth = 300.0 + (deepest - 300.0) * torch.rand(24, 18, generator=g, dtype=torch.float64)
    return depth, torch.rand(24, 18, generator=g) > 0.25


@pytest.mark.parametrize("name", ["d.npy", "d.tiff", "d.tif", "d.png"])
def test_write_depth_round_trips_every_format(tmp_path, name):
    depth, valid = _depth_and_mask()
    written = write_depth(tmp_path / name, depth, valid)
    back = read_depth(written.path)
    assert back.dtype == torch.float32 and back.shape == (24, 18)
    assert torch.equal(torch.isfinite(back), valid)
    err = (back.double() - depth)[valid].abs().max()
    if written.format == "png":
        assert written.scale == 32.0 and written.clipped == 0 and written.sidecar == tmp_path / "d.json"
        assert err <= 0.5 / 32 + 1e-4
    else:
        assert written.scale is None and written.sidecar is None and err < 1e-4  # float32 exactly


@pytest.mark.parametrize("name", ["d.npy", "d.tiff", "d.png"])
def test_numpy_arrays_write_the_same_files_as_tensors(tmp_path, name):
    depth, valid = _depth_and_mask()
    written = write_depth(tmp_path / f"t_{name}", depth, valid)
    again = write_depth(tmp_path / f"a_{name}", depth.numpy(), valid.numpy())
    assert written.scale == again.scale and written.path.read_bytes() == again.path.read_bytes()
    with pytest.raises(ShapeError, match=r"depth must have shape \(H, W\), got \(1, 24, 18\)"):
        write_depth(tmp_path / "x.npy", depth.numpy()[None])
    with pytest.raises(ShapeError, match=r"valid must have shape \(24, 18\), got \(18, 24\)"):
        write_depth(tmp_path / "x.npy", depth.numpy(), valid.numpy().T)


def test_decode_image_is_read_image_without_torch(tmp_path):
    rgb = torch.rand(3, 20, 30, generator=torch.Generator().manual_seed(3))
    write_image(tmp_path / "c.png", rgb, bits=16)
    decoded = decode_image(tmp_path / "c.png")
    assert decoded.dtype == np.float32 and decoded.shape == (3, 20, 30) and decoded.flags.c_contiguous
    assert torch.equal(torch.from_numpy(decoded), read_image(tmp_path / "c.png"))
    with pytest.raises(ImageIOError, match="image not found"):
        decode_image(tmp_path / "missing.png")


def test_writing_depth_files_and_previews_needs_no_torch(tmp_path):
    import subprocess
    import sys

    code = ("import sys, numpy as np; from prismstereo.io import write_depth; "
            "from prismstereo.preview import write_depth_preview\n"
            f"write_depth(r'{tmp_path / 'd.png'}', np.full((8, 6), 500.0), np.ones((8, 6), bool))\n"
            f"write_depth_preview(r'{tmp_path / 'p.png'}', np.full((8, 6), 500.0))\n"
            "print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False" and (tmp_path / "d.png").is_file() and (tmp_path / "p.png").is_file()


def test_depth_png_scale_reference_values_and_storage(tmp_path):
    assert depth_png_scale(torch.full((2, 2), 255.9)) == 256.0  # the endoscopy convention where it fits
    assert depth_png_scale(torch.full((2, 2), 256.1)) == 128.0
    assert depth_png_scale(torch.full((2, 2), 1374.0)) == 32.0  # the thesis' range
    assert depth_png_scale(torch.full((2, 2), 1e9), torch.zeros(2, 2, dtype=torch.bool)) == 256.0  # none valid
    depth, valid = _depth_and_mask(900.0)
    written = write_depth(tmp_path / "a.png", depth, valid)
    assert written.scale == 64.0
    (tmp_path / "a.json").unlink()  # the text chunk alone suffices
    assert torch.allclose(read_depth(tmp_path / "a.png")[valid].double(), depth[valid], atol=0.5 / 64 + 1e-4)
    legacy = tmp_path / "legacy.png"  # a PNG without a stored scale (another tool's): read at 256
    write_depth_png(legacy, torch.full((4, 4), 100.0))
    assert torch.allclose(read_depth(legacy), torch.full((4, 4), 100.0))
    assert torch.allclose(read_depth(tmp_path / "a.png", scale=128.0)[valid].double(), depth[valid] / 2, atol=0.01)
    clipped = write_depth(tmp_path / "c.png", depth, valid, png_scale=256.0)
    assert clipped.scale == 256.0 and clipped.clipped == int((valid & (depth * 256 > 65535)).sum()) > 0


def test_depth_file_errors(tmp_path):
    depth = torch.full((4, 4), 500.0)
    with pytest.raises(ImageIOError, match="cannot tell the depth format of .*d.exr"):
        write_depth(tmp_path / "d.exr", depth)
    with pytest.raises(ImageIOError, match="unknown depth format 'exr'. Choose from: npy, png, tiff"):
        write_depth(tmp_path / "d", depth, format="exr")
    with pytest.raises(ImageIOError, match="format 'npy' contradicts the file name d.png"):
        write_depth(tmp_path / "d.png", depth, format="npy")
    with pytest.raises(ImageIOError, match="depth map not found"):
        read_depth(tmp_path / "missing.tiff")
    np.save(tmp_path / "ints.npy", np.zeros((4, 4), np.int32))
    with pytest.raises(ImageIOError, match="must be a 2-D float array"):
        read_depth(tmp_path / "ints.npy")
    write_depth(tmp_path / "s.png", depth)
    (tmp_path / "s.json").write_text("{}")
    from PIL import Image

    Image.open(tmp_path / "s.png").save(tmp_path / "plain.png")  # without the text chunk
    (tmp_path / "plain.json").write_text('{"scale": 3}')
    with pytest.raises(ImageIOError, match="unreadable depth scale in .*plain.json"):
        read_depth(tmp_path / "plain.png")


@pytest.mark.parametrize("levels", [None, 255, 65535])
def test_grey_array_is_to_grey_bit_for_bit(levels):
    """The numpy grey of a colour image (random, 8-bit and 16-bit levels) equals torch's to_grey in every bit."""
    from prismstereo.conventions import to_grey
    from prismstereo.io import grey_array

    g = torch.Generator().manual_seed(5)
    image = torch.rand(2, 3, 61, 83, generator=g)
    if levels is not None:
        image = (image * levels).round() / levels
    assert np.array_equal(grey_array(image.numpy()), to_grey(image).numpy())
    one = np.zeros((1, 4, 4), np.float32)
    assert grey_array(one) is one
    with pytest.raises(ShapeError, match="float32"):
        grey_array(np.zeros((3, 4, 4)))
    with pytest.raises(ShapeError, match="C = 1 or 3"):
        grey_array(np.zeros((2, 4, 4), np.float32))
