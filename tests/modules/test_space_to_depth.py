"""Space-to-depth first convolution and shared input conversion of the paper CNN encoders."""

import pytest
import torch

from navformer_rl.modules.models.cnn import (
    ConvEncoder,
    encode_images,
    pixels_space_to_depth,
)
from navformer_rl.modules.models.resnet import ResNet18Encoder


def _pixels(*shape: int, seed: int = 0) -> torch.Tensor:
    return torch.randint(
        0, 256, (*shape, 84, 84, 3), dtype=torch.uint8, generator=torch.Generator().manual_seed(seed)
    )


def _encoder_pair(**options) -> tuple[ConvEncoder, ConvEncoder]:
    torch.manual_seed(0)
    plain = ConvEncoder(**options)
    blocked = ConvEncoder(**options, space_to_depth=True)
    blocked.load_state_dict(plain.state_dict())  # same parameters: space_to_depth only changes the layout
    return plain, blocked


def test_pixels_space_to_depth_channel_order():
    pixels = _pixels(2)
    blocks = pixels_space_to_depth(pixels)
    assert blocks.shape == (2, 21, 21, 48) and blocks.dtype == torch.uint8
    for i, j, dy, dx, c in [(0, 0, 0, 0, 0), (3, 7, 1, 2, 1), (20, 20, 3, 3, 2), (5, 0, 2, 3, 0)]:
        assert blocks[1, i, j, dy * 12 + dx * 3 + c] == pixels[1, 4 * i + dy, 4 * j + dx, c]


@pytest.mark.parametrize("channels_last", [True, False])
def test_space_to_depth_encoder_equals_the_plain_encoder(channels_last):
    plain, blocked = _encoder_pair(channels_last=channels_last, micro_batch=4)
    pixels = _pixels(3, 3, seed=1)
    torch.testing.assert_close(blocked(pixels), plain(pixels), rtol=1e-5, atol=1e-5)
    floats = torch.rand(5, 3, 84, 84, generator=torch.Generator().manual_seed(2))
    torch.testing.assert_close(
        blocked.forward_float(floats), plain.forward_float(floats), rtol=1e-5, atol=1e-5
    )


def test_space_to_depth_encoder_has_the_same_gradients():
    plain, blocked = _encoder_pair()
    pixels = _pixels(4, seed=3)
    plain(pixels).square().sum().backward()
    blocked(pixels).square().sum().backward()
    for (name, a), b in zip(plain.named_parameters(), blocked.parameters()):
        torch.testing.assert_close(b.grad, a.grad, rtol=1e-4, atol=1e-5, msg=name)


def test_space_to_depth_under_bf16_autocast_stays_close():
    plain, blocked = _encoder_pair()
    pixels = _pixels(6, seed=4)
    reference = plain(pixels)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        got = blocked(pixels)
    assert got.dtype == torch.bfloat16
    assert (got.float() - reference).abs().max() < 0.05 * reference.abs().max()


def test_encode_images_shares_the_conversion_and_stacks_in_order():
    torch.manual_seed(0)
    first, second = ConvEncoder(micro_batch=3), ConvEncoder(micro_batch=3)
    pixels = _pixels(2, 4, seed=5)
    out = encode_images([first, second], pixels)
    assert out.shape == (2, 4, 2, 128)
    torch.testing.assert_close(out[:, :, 0], first(pixels))
    torch.testing.assert_close(out[:, :, 1], second(pixels))


def test_encode_images_refuses_encoders_with_different_layouts():
    with pytest.raises(ValueError, match="input layout"):
        encode_images([ConvEncoder(), ConvEncoder(space_to_depth=True)], _pixels(1))
    with pytest.raises(ValueError, match="input layout"):
        encode_images([ConvEncoder(), ResNet18Encoder()], _pixels(1))
    with pytest.raises(ValueError, match="image_size % 4"):
        ConvEncoder(image_size=82, space_to_depth=True)


def test_encode_nchw_names_a_bad_input_shape():
    with pytest.raises(ValueError, match=r"\(2, 5, 84, 84\)"):
        ConvEncoder().encode_nchw(torch.zeros(2, 5, 84, 84))
