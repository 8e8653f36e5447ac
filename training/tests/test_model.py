"""The network of Kallweit 2017 §4.3: shapes, size, progressive feeding, residual path."""

import numpy as np
import pytest
import torch

from rpnn.model import DESCRIPTOR_LEN, RPNN, log_loss, parameter_count


def test_shapes_and_output_count():
    for outputs in (1, 3):
        m = RPNN(outputs=outputs)
        y = m(torch.rand(7, DESCRIPTOR_LEN))
        assert y.shape == (7, outputs)
        assert torch.all(y >= 0)  # the last layer is a ReLU (o^M = f(...), §4.3)
    assert RPNN().input_len == DESCRIPTOR_LEN == 2251


def test_parameter_count_of_the_paper_configuration():
    m = RPNN()
    # 10 blocks: V (226 -> 200, with b1), W2 (200 -> 200, with b2), W1 (200 -> 200) for blocks
    # 2..10 (o_0 = 0); head: 200 -> 200 -> 200 -> 1 with biases.
    expected = 10 * (226 * 200 + 200) + 10 * (200 * 200 + 200) + 9 * 200 * 200 \
        + 2 * (200 * 200 + 200) + 201
    assert parameter_count(m) == expected == 1_296_601
    # The paper reports "about 1.4 million" for its MLPs; ours is within 10 % of that.
    assert abs(expected - 1.4e6) / 1.4e6 < 0.1
    layers = 2 * len(m.blocks) + len(m.head)
    assert layers == 23


def block_outputs(m: RPNN, x: torch.Tensor) -> list[torch.Tensor]:
    outs, o = [], None
    for k, block in enumerate(m.blocks):
        o = block(m.level_input(x, k), o)
        outs.append(o)
    return outs


def test_block_k_sees_only_level_k():
    torch.manual_seed(1)
    m = RPNN(width=32).eval()
    x = torch.rand(16, DESCRIPTOR_LEN) * 2
    base = block_outputs(m, x)
    for j in range(10):
        x2 = x.clone()
        x2[:, j * 225 : (j + 1) * 225] += torch.rand(16, 225) * 3
        outs = block_outputs(m, x2)
        for k in range(10):
            same = torch.equal(outs[k], base[k])
            # Blocks before j cannot see level j; block j does.
            assert same == (k < j), (j, k)
    # gamma reaches every block.
    x3 = x.clone()
    x3[:, -1] += 0.5
    assert not torch.equal(block_outputs(m, x3)[0], base[0])


def test_level_input_layout():
    m = RPNN()
    x = torch.arange(DESCRIPTOR_LEN, dtype=torch.float32)[None]
    z3 = m.level_input(x, 3)[0]
    assert z3.shape == (226,)
    assert z3[0] == 3 * 225 and z3[224] == 4 * 225 - 1 and z3[225] == 2250


def test_residual_path_is_identity_when_the_block_is_silent():
    torch.manual_seed(2)
    m = RPNN(width=16).eval()
    x = torch.rand(5, DESCRIPTOR_LEN)
    with torch.no_grad():
        m.blocks[4].W2.weight.zero_()
        m.blocks[4].W2.bias.zero_()
    outs = block_outputs(m, x)
    # o_5 = ReLU(0 + o_4) = o_4 since o_4 >= 0.
    assert torch.equal(outs[4], outs[3])


def test_log_loss():
    y = torch.tensor([0.0, 1.0, 3.0])
    assert float(log_loss(y, y)) == 0.0
    got = float(log_loss(torch.tensor([np.e - 1]), torch.tensor([0.0])))
    assert got == pytest.approx(1.0, rel=1e-6)


def test_bad_configuration_is_refused():
    with pytest.raises(ValueError):
        RPNN(width=0)
