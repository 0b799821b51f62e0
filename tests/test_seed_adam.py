"""The stacked networks' flat parameter buffer and the fused Adam on it, each against an
independent computation: torch's plain Adam on separate tensors, the gradients backward
gives separate tensors, and each seed alone against the seed in a batch."""
import pytest
import torch
from torch import nn

from trl_dgpq.agents.neural import LINE, SeedAdam, SeedStack, Target, build_per_seed


def mlp():
    return nn.Sequential(nn.Linear(3, 5), nn.ReLU(), nn.Linear(5, 2))


def stack_and_copies(seeds):
    """A SeedStack and, independently, each seed's plain network with the same weights."""
    nets = build_per_seed(mlp, seeds)
    plain = [[nn.Parameter(p.detach().clone()) for p in net.parameters()] for net in nets]
    return SeedStack(nets), plain


def stacked(t):
    """A plain nn.Linear tensor as SeedLinear holds it: weights (in, out), transposed."""
    return t.T if t.dim() == 2 else t


def plain_forward(params, x):
    w1, b1, w2, b2 = params
    return torch.relu(x @ w1.T + b1) @ w2.T + b2


def test_the_buffer_is_whole_lines_each_parameter_a_block_starting_on_one():
    stack, _ = stack_and_copies([0, 1, 2])
    flat = stack.flat
    assert flat.data.numel() % LINE == 0 and flat.grad.shape == flat.data.shape
    ends = []
    for p in stack.parameters():
        assert p.untyped_storage().data_ptr() == flat.data.untyped_storage().data_ptr()
        assert p.grad.untyped_storage().data_ptr() == flat.grad.untyped_storage().data_ptr()
        assert p.is_contiguous() and p.storage_offset() % LINE == 0 and p.grad.storage_offset() == p.storage_offset()
        ends.append((p.storage_offset(), p.storage_offset() + p.numel()))
    assert all(a[1] <= b[0] for a, b in zip(ends, ends[1:]))  # blocks do not overlap
    used = torch.zeros(flat.data.numel(), dtype=torch.bool)
    for a, b in ends:
        used[a:b] = True
    assert not flat.data[~used].any() and int((~used).sum()) > 0  # padding, zero


def test_the_weights_are_each_seeds_own_and_the_forward_is_the_plain_networks():
    stack, plain = stack_and_copies([0, 1, 2])
    x = torch.randn(3, 4, 3, generator=torch.Generator().manual_seed(0))
    y = stack(x)
    for i in range(3):
        torch.testing.assert_close(y[i], plain_forward(plain[i], x[i]), rtol=1e-6, atol=1e-6)


def test_backward_adds_into_the_gradient_buffer_and_zero_grad_keeps_the_views():
    stack, plain = stack_and_copies([0, 1])
    optim = SeedAdam(stack, lr=0.1)
    x = torch.randn(2, 4, 3, generator=torch.Generator().manual_seed(1))
    views = [p.grad for p in stack.parameters()]
    stack(x).square().sum().backward()
    for i in range(2):
        plain_forward(plain[i], x[i]).square().sum().backward()
    for p, grad in zip(stack.parameters(), views):
        assert p.grad is grad  # written into, not replaced
    for k, p in enumerate(stack.parameters()):
        for i in range(2):
            torch.testing.assert_close(p.grad[i], stacked(plain[i][k].grad), rtol=1e-6, atol=1e-6)
    first = stack.flat.grad.clone()
    stack(x).square().sum().backward()  # a second backward adds, as for any parameter
    torch.testing.assert_close(stack.flat.grad, 2 * first)
    optim.zero_grad()
    assert not stack.flat.grad.any() and all(p.grad is g for p, g in zip(stack.parameters(), views))


def test_fused_adam_on_the_buffer_is_torchs_adam_per_tensor():
    """Three steps against torch's single-tensor Adam on separate copies: the same weights and
    moments to float32 rounding (the fused arithmetic rounds its own way), padding left at zero."""
    stack, plain = stack_and_copies([0, 1, 2])
    optim = SeedAdam(stack, lr=0.05)
    assert optim.param_groups[0]["fused"]  # the one-pass kernel: what the buffer is for
    ref = [torch.optim.Adam(ps, lr=0.05, foreach=False) for ps in plain]
    g = torch.Generator().manual_seed(2)
    for _ in range(3):
        optim.zero_grad()
        grads = [torch.randn(p.shape, generator=g) for p in stack.parameters()]
        for p, grad in zip(stack.parameters(), grads):
            p.grad.copy_(grad)
        optim.step()
        for i, (ps, o) in enumerate(zip(plain, ref)):
            for p, grad in zip(ps, grads):
                p.grad = stacked(grad[i]).clone()
            o.step()
    for k, p in enumerate(stack.parameters()):
        for i in range(3):
            torch.testing.assert_close(p.detach()[i], stacked(plain[i][k].detach()), rtol=1e-6, atol=1e-7)
    moments = optim.seed_tensors()
    assert len(moments) == 8  # exp_avg of the four tensors, then exp_avg_sq
    for i in range(3):
        for k, p in enumerate(plain[i]):
            state = ref[i].state[p]
            torch.testing.assert_close(moments[k][i], stacked(state["exp_avg"]), rtol=1e-6, atol=1e-8)
            torch.testing.assert_close(moments[4 + k][i], stacked(state["exp_avg_sq"]), rtol=1e-6, atol=1e-10)
    used = torch.zeros(stack.flat.data.numel(), dtype=torch.bool)
    for p in stack.parameters():
        used[p.storage_offset():p.storage_offset() + p.numel()] = True
    assert not stack.flat.data[~used].any()


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("sizes", [(3, 1), (2, 3), (5, 2), (40, 30)])
def test_a_seed_alone_is_the_seed_in_any_batch_bit_for_bit(sizes, threads):
    """Fused Adam's vectorised and scalar parts round differently (here, vectors of 8 floats): a
    seed's 4 floats ((3, 1): weight and bias) alone fall wholly in the scalar part, in a batch of
    2 in a vector. Blocks of whole cache lines keep every element in the vectorised part: seed i's
    weights after 5 steps are the same bits alone and in batches of 2, 3, 5 and 8 (unpadded
    blocks fail this for (3, 1) and (5, 2)). With 2 threads the kernel splits its work between them,
    at whole lines."""
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        run_seed_batches(sizes)
    finally:
        torch.set_num_threads(before)


def run_seed_batches(sizes):
    n_in, n_out = sizes
    g = torch.Generator().manual_seed(3)
    grads = {i: [torch.randn(n_in, n_out, generator=g), torch.randn(n_out, generator=g)] for i in range(8)}
    weights = {}
    for seeds in ([0], [1], [2], [0, 1], [2, 0, 1], list(range(5)), list(range(8))):
        stack = SeedStack(build_per_seed(lambda: nn.Sequential(nn.Linear(n_in, n_out)), seeds))
        optim = SeedAdam(stack, lr=0.01)
        for step in range(5):
            optim.zero_grad()
            for k, p in enumerate(stack.parameters()):  # weight (S, in, out), bias (S, out)
                p.grad.copy_(torch.stack([grads[s][k] * (step + 1) for s in seeds]))
            optim.step()
        for row, s in enumerate(seeds):
            got = [p.detach()[row].clone() for p in stack.parameters()]
            if s in weights:
                assert all(torch.equal(a, b) for a, b in zip(got, weights[s])), (s, seeds)
            else:
                weights[s] = got
    assert set(weights) == set(range(8))


def test_a_target_has_its_own_buffer_follows_by_copies_and_soft_updates_and_takes_no_gradient():
    stack, _ = stack_and_copies([0, 1])
    target = Target(stack)
    assert target.net.flat.data.data_ptr() != stack.flat.data.data_ptr()
    assert target.net.flat.grad is None and not target.net.flat.param.requires_grad  # no gradient buffer kept
    assert all(not p.requires_grad and p.grad is None for p in target.parameters())
    for p, q in zip(target.parameters(), stack.parameters()):
        assert p.untyped_storage().data_ptr() == target.net.flat.data.untyped_storage().data_ptr()
        assert torch.equal(p, q.detach())
    with torch.no_grad():
        for q in stack.parameters():
            q.add_(1.0)
    before = [p.clone() for p in target.parameters()]
    target.soft_update_(0.25)
    for p, b, q in zip(target.parameters(), before, stack.parameters()):
        torch.testing.assert_close(p, b + 0.25 * (q.detach() - b))
    target.copy_()
    assert all(torch.equal(p, q.detach()) for p, q in zip(target.parameters(), stack.parameters()))


def test_an_earlier_versions_adam_state_per_tensor_is_packed_into_the_buffer():
    """A checkpoint written before the flat buffer holds torch's Adam state per layer tensor:
    loaded, each moment lands in its tensor's block and the step count is kept; a state for
    another network is refused."""
    stack, _ = stack_and_copies([0, 1])
    old = torch.optim.Adam(list(stack.parameters()), lr=0.02, foreach=True)
    g = torch.Generator().manual_seed(4)
    for _ in range(2):
        for p in stack.parameters():
            p.grad.copy_(torch.randn(p.shape, generator=g))
        old.step()
    saved = old.state_dict()
    optim = SeedAdam(stack, lr=0.02)
    optim.load_state_dict(saved)
    moments = optim.seed_tensors()
    per = [saved["state"][i] for i in range(4)]
    for k in range(4):
        assert torch.equal(moments[k], per[k]["exp_avg"]) and torch.equal(moments[4 + k], per[k]["exp_avg_sq"])
    (state,) = optim.state.values()
    assert float(state["step"]) == 2.0 and optim.param_groups[0]["fused"] and optim.param_groups[0]["lr"] == 0.02
    optim.step()  # and it goes on from there
    assert float(state["step"]) == 3.0
    with pytest.raises(ValueError, match="3 tensors, the network 4"):
        optim.load_state_dict({"state": {}, "param_groups": [{**saved["param_groups"][0], "params": [0, 1, 2]}]})


def test_an_earlier_versions_adam_that_never_stepped_loads_empty():
    stack, _ = stack_and_copies([0, 1])
    old = torch.optim.Adam(list(stack.parameters()), lr=0.02, foreach=True)
    optim = SeedAdam(stack, lr=0.02)
    optim.load_state_dict(old.state_dict())
    assert not optim.state and optim.param_groups[0]["fused"]
    optim.step()
    (state,) = optim.state.values()
    assert float(state["step"]) == 1.0


@pytest.mark.parametrize("cut", ["Module.zero_grad", "double", "load_state_dict(assign=True)"])
def test_a_step_refuses_once_the_parameters_are_no_longer_views_of_the_buffer(cut):
    """Each of these replaces the parameters or their gradients with tensors of their own: Adam would
    step a buffer nothing reads any more, and learning would stop without a word."""
    stack, _ = stack_and_copies([0, 1])
    optim = SeedAdam(stack, lr=0.1)
    x = torch.randn(2, 4, 3, generator=torch.Generator().manual_seed(5))
    stack(x).sum().backward()
    optim.step()  # as built: fine
    if cut == "Module.zero_grad":
        stack.zero_grad()  # sets every .grad to None
    elif cut == "double":
        stack.double()
        x = x.double()
    else:
        stack.load_state_dict({k: v.clone() for k, v in stack.state_dict().items()}, assign=True)
    stack(x).sum().backward()
    with pytest.raises(RuntimeError, match=r"^a stacked network's parameters or gradients were replaced \(by Module"
                                           r"\.zero_grad, \.to\(\), a dtype cast or load_state_dict\(assign=True\)\): "
                                           r"they are views of its flat buffers, which its optimiser steps; zero "
                                           r"gradients with the optimiser's zero_grad$"):
        optim.step()


def test_a_target_refuses_a_network_with_parameters_outside_its_stacks():
    stack, _ = stack_and_copies([0, 1])
    net = nn.ModuleList([stack, nn.Linear(2, 2)])
    with pytest.raises(TypeError, match="^a Target follows networks whose parameters are all in SeedStacks$"):
        Target(net)


def test_an_earlier_versions_state_of_some_tensors_only_is_refused():
    stack, _ = stack_and_copies([0, 1])
    old = torch.optim.Adam(list(stack.parameters()), lr=0.02, foreach=True)
    for p in stack.parameters():
        p.grad.fill_(1.0)
    old.step()
    saved = old.state_dict()
    del saved["state"][2]
    with pytest.raises(ValueError, match="^the optimiser state covers some of the network's tensors, not all: it "
                                         "cannot be packed into one buffer$"):
        SeedAdam(stack, lr=0.02).load_state_dict(saved)
