"""World-model and behaviour loss pieces: KL balancing with free bits, lambda-returns, return
normalisation, the slow critic, and RSSM resets on is_first."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from d2a_core.agents.dreamer import native
from d2a_core.agents.dreamer.behavior import Behavior, ReturnNormalizer, frozen, lambda_returns
from d2a_core.agents.dreamer.distributions import TwoHot, symlog
from d2a_core.agents.dreamer.latent import Latent
from d2a_core.agents.dreamer.world_model import WorldModel, kl_balance


def _logits_with_kl(per_latent_kl_target: float, latents: int, classes: int = 2) -> tuple[torch.Tensor, torch.Tensor]:
    """Posterior/prior logits of two-class latents whose KL per latent is about the target."""
    prior = torch.zeros(latents, classes)  # uniform
    # KL(Bernoulli(p) || 1/2) = log 2 - H(p); solve for p by bisection.
    low, high = 0.5, 1.0
    for _ in range(60):
        p = (low + high) / 2
        kl = math.log(2) + p * math.log(p) + (1 - p) * math.log(1 - p)
        low, high = (p, high) if kl < per_latent_kl_target else (low, p)
    post = torch.tensor([[math.log(p), math.log(1 - p)]]).repeat(latents, 1)
    return post.unsqueeze(0), prior.unsqueeze(0)


def test_free_bits_apply_to_the_kl_summed_over_latents():
    # 32 latents with 0.1 nats each: 3.2 nats in total, above the 1-nat floor. Clipping each
    # latent separately would give max(1, 0.1) * 32 = 32 and no gradient at all.
    post, prior = _logits_with_kl(0.1, latents=32)
    post.requires_grad_(True)
    prior.requires_grad_(True)
    loss, dyn, rep = kl_balance(post, prior, unimix=0.0, free_nats=1.0, dyn_scale=0.5, rep_scale=0.1)
    assert dyn.item() == pytest.approx(3.2, rel=1e-3)
    assert loss.item() == pytest.approx(0.6 * 3.2, rel=1e-3)
    loss.sum().backward()
    assert post.grad.abs().sum() > 0 and prior.grad.abs().sum() > 0

    # Below the floor in total (32 * 0.02 = 0.64 nats) the loss is constant: no gradient.
    post, prior = _logits_with_kl(0.02, latents=32)
    post.requires_grad_(True)
    prior.requires_grad_(True)
    loss, dyn, _ = kl_balance(post, prior, unimix=0.0, free_nats=1.0, dyn_scale=0.5, rep_scale=0.1)
    assert dyn.item() == pytest.approx(0.64, rel=1e-3)
    assert loss.item() == pytest.approx(0.6, rel=1e-6)
    loss.sum().backward()
    assert post.grad.abs().sum() == 0 and prior.grad.abs().sum() == 0


def test_kl_balance_sends_dyn_to_prior_and_rep_to_posterior():
    generator = torch.Generator().manual_seed(0)
    post = (3 * torch.randn(2, 8, 4, generator=generator)).requires_grad_(True)
    prior = torch.randn(2, 8, 4, generator=generator).requires_grad_(True)

    dyn_only, _, _ = kl_balance(post, prior, 0.01, 0.0, dyn_scale=0.5, rep_scale=0.0)
    post_grad, prior_grad = torch.autograd.grad(dyn_only.sum(), (post, prior))
    assert post_grad.abs().sum() == 0 and prior_grad.abs().sum() > 0

    rep_only, _, _ = kl_balance(post, prior, 0.01, 0.0, dyn_scale=0.0, rep_scale=0.1)
    post_grad, prior_grad = torch.autograd.grad(rep_only.sum(), (post, prior))
    assert post_grad.abs().sum() > 0 and prior_grad.abs().sum() == 0

    # Values: both terms measure the same KL, weighted 0.5 and 0.1.
    both, dyn, rep = kl_balance(post, prior, 0.01, 0.0, 0.5, 0.1)
    assert torch.allclose(dyn, rep)
    assert torch.allclose(both, 0.6 * dyn)


def test_lambda_returns_match_a_hand_computed_three_step_case():
    rewards = torch.tensor([[1.0], [2.0], [3.0]])  # r_1, r_2, r_3
    discounts = torch.tensor([[0.9], [0.8], [0.5]])  # gamma * continue_1..3
    values = torch.tensor([[10.0], [20.0], [30.0], [40.0]])  # v_0..v_3
    lam = 0.5
    r3 = 40.0
    r2 = 3.0 + 0.5 * ((1 - lam) * 40.0 + lam * r3)
    r1 = 2.0 + 0.8 * ((1 - lam) * 30.0 + lam * r2)
    r0 = 1.0 + 0.9 * ((1 - lam) * 20.0 + lam * r1)
    returns = lambda_returns(rewards, discounts, values, lam)
    assert returns[:, 0].tolist() == pytest.approx([r0, r1, r2])
    # lambda = 1: discounted reward sum bootstrapped at the end; lambda = 0: one-step TD targets.
    mc = lambda_returns(rewards, discounts, values, 1.0)[0, 0].item()
    assert mc == pytest.approx(1 + 0.9 * (2 + 0.8 * (3 + 0.5 * 40)))
    td = lambda_returns(rewards, discounts, values, 0.0)[:, 0]
    assert td.tolist() == pytest.approx([1 + 0.9 * 20, 2 + 0.8 * 30, 3 + 0.5 * 40])


def test_return_normaliser_tracks_percentile_range_with_ema():
    norm = ReturnNormalizer(decay=0.99, low_percent=5, high_percent=95, limit=1.0)
    returns = torch.linspace(0.0, 100.0, 10001)
    low, high = norm.candidate(returns)
    assert (low.item(), high.item()) == pytest.approx((5.0, 95.0), abs=1e-3)
    assert norm.scale(low, high).item() == pytest.approx(90.0, abs=1e-3)
    assert not bool(norm.initialized)  # nothing stored before commit
    norm.commit(low, high)
    # A new batch with range [0, 10] only moves the EMA by 1 %.
    low, high = norm.candidate(torch.linspace(0.0, 10.0, 10001))
    assert low.item() == pytest.approx(0.99 * 5.0 + 0.01 * 0.5, abs=1e-3)
    assert high.item() == pytest.approx(0.99 * 95.0 + 0.01 * 9.5, abs=1e-3)
    # Small ranges are not amplified: scale is max(1, hi - lo).
    small = ReturnNormalizer(0.99, 5, 95, 1.0)
    low, high = small.candidate(torch.linspace(-0.2, 0.2, 101))
    assert small.scale(low, high).item() == 1.0


def _world_model_with_constant_reward(config, value: float) -> WorldModel:
    """A world model whose reward head predicts `value` everywhere (its output layer is
    zero-initialised, so its bias alone sets the prediction)."""
    torch.manual_seed(0)
    model = WorldModel(obs_size=3, action_size=1, config=config)
    twohot = TwoHot(config.bins, config.bin_range)
    code = twohot.encode(torch.tensor([value]))[0]
    with torch.no_grad():
        model.reward_head.out.bias.copy_(torch.log(code + 1e-8))
        model.continue_head.out.bias.fill_(20.0)  # episodes continue
    return model


def test_return_normalisation_is_active_in_the_actor_loss(make_agent):
    """Actor losses for rewards 10 and 100 differ by far less than 10x: advantages are divided
    by the (large) return range. Without normalisation they would differ 10x."""
    config = make_agent().config
    losses, scales = [], []
    for value in (10.0, 100.0):
        model = _world_model_with_constant_reward(config, value)
        torch.manual_seed(1)
        behavior = Behavior(action_size=1, discrete=False, config=config)
        generator = torch.Generator().manual_seed(2)
        start = model.rssm.initial(64)
        start = Latent(start.h + 0.1 * torch.randn(64, config.deter), start.index, start.probs)
        out = behavior.losses(model, start, torch.ones(64), generator)
        low, high = out.metrics["return_norm/low"].item(), out.metrics["return_norm/high"].item()
        assert out.metrics["return_norm/scale"].item() == pytest.approx(max(1.0, high - low))
        scales.append(out.metrics["return_norm/scale"].item())
        losses.append(out.actor_loss.item())
    assert scales[0] > 5 and scales[1] > 5 * scales[0]
    assert 0.8 < losses[1] / losses[0] < 1.25


def test_slow_critic_follows_the_critic_by_ema(make_agent):
    config = make_agent().config
    behavior = Behavior(action_size=1, discrete=False, config=config)
    with torch.no_grad():
        for p in behavior.critic.parameters():
            p.fill_(1.0)
        for p in behavior.slow_critic.parameters():
            p.fill_(0.0)
    behavior.update_slow_critic()
    for p in behavior.slow_critic.parameters():
        assert torch.allclose(p, torch.full_like(p, 0.02))
    behavior.update_slow_critic()
    for p in behavior.slow_critic.parameters():
        assert torch.allclose(p, torch.full_like(p, 0.02 + 0.98 * 0.02 + 0.0))  # 1 - 0.98^2
    assert not any(p.requires_grad for p in behavior.slow_critic.parameters())


def test_rssm_resets_state_where_is_first(make_agent):
    """After an is_first step the posterior does not depend on what came before."""
    config = make_agent().config
    torch.manual_seed(0)
    model = WorldModel(obs_size=3, action_size=2, config=config)
    length = 6
    embed = model.embed(torch.randn(2, length, 3))
    actions = torch.randn(2, length, 2)
    embed[1, :3] = model.embed(torch.randn(1, 3, 3))[0]  # different history in sequence 1
    actions[1, :3] = torch.randn(3, 2)
    embed[1, 3:] = embed[0, 3:]
    actions[1, 3:] = actions[0, 3:]  # actions[:, 3] is the action before step 3: masked on reset
    is_first = torch.zeros(2, length, dtype=torch.bool)
    is_first[:, 0] = True
    is_first[:, 3] = True
    seeds = torch.Generator().manual_seed(5)
    out = model.rssm.observe(embed, actions, is_first, seeds)
    assert not torch.allclose(out.post_logits[0, 2], out.post_logits[1, 2])
    # Same random numbers per (time, batch row) would be needed for equal samples; compare the
    # step right at the reset, which only depends on the initial state and embedding.
    assert torch.allclose(out.post_logits[0, 3], out.post_logits[1, 3], atol=1e-5)
    assert torch.allclose(out.latent.h[0, 3], out.latent.h[1, 3], atol=1e-6)

    # Without the reset the history leaks through.
    is_first[:, 3] = False
    out = model.rssm.observe(embed, actions, is_first, torch.Generator().manual_seed(5))
    assert not torch.allclose(out.latent.h[0, 3], out.latent.h[1, 3], atol=1e-3)


@pytest.mark.parametrize(("unimix", "kernels"), [(0.01, True), (0.0, True), (0.01, False)])
def test_filtering_backward_matches_autograd(make_agent, monkeypatch, unimix, kernels):
    """The filtering loop's hand-written backward pass gives autograd's gradients, through
    mid-sequence resets to a learned initial state, for gradients arriving at every output;
    with the compiled CPU kernels and with PyTorch ops only."""
    if not kernels:
        monkeypatch.setattr(native, "usable", lambda *tensors: False)
    config = make_agent(unimix=unimix).config
    torch.manual_seed(0)
    model = WorldModel(obs_size=3, action_size=2, config=config)
    with torch.no_grad():
        model.rssm.initial_deter.normal_()  # a non-zero initial state, so its gradient matters
    batch, length = 5, 9
    obs, actions = torch.randn(batch, length, 3), torch.randn(batch, length, 2)
    is_first = torch.zeros(batch, length, dtype=torch.bool)
    is_first[:, 0] = True
    is_first[1, 4] = is_first[3, 6] = is_first[4, 8] = True
    outputs = {}
    for name, observe in (("manual", model.rssm.observe), ("autograd", model.rssm.observe_autograd)):
        model.zero_grad()
        out = observe(model.embed(obs), actions, is_first, torch.Generator().manual_seed(3))
        weights = torch.Generator().manual_seed(4)  # same random cotangents for both
        loss = sum(
            (tensor * torch.randn(tensor.shape, generator=weights)).sum()
            for tensor in (out.latent.h, out.latent.probs, out.post_logits, out.prior_logits)
        )
        loss.backward()
        grads = {n: p.grad.clone() for n, p in model.named_parameters() if p.grad is not None}
        outputs[name] = (out, grads)
    (manual, manual_grads), (reference, reference_grads) = outputs["manual"], outputs["autograd"]
    assert torch.equal(manual.latent.index, reference.latent.index)
    assert torch.allclose(manual.latent.h, reference.latent.h, atol=1e-6)
    assert torch.allclose(manual.post_logits, reference.post_logits, atol=1e-6)
    assert set(manual_grads) == set(reference_grads)
    assert "rssm.initial_deter" in manual_grads and "rssm.img_in.table" in manual_grads
    for name, grad in reference_grads.items():
        scale = grad.abs().max().clamp(min=1e-6)
        assert (manual_grads[name] - grad).abs().max() / scale < 1e-4, name


def test_symlog_mse_decoder_target(make_agent):
    """The decoder regresses symlog(obs): a huge observation gives a moderate loss."""
    config = make_agent().config
    torch.manual_seed(0)
    model = WorldModel(obs_size=3, action_size=2, config=config)
    batch = {
        "obs": torch.full((1, 4, 3), 1e6),
        "action": torch.zeros(1, 4, 2),
        "reward": torch.zeros(1, 4),
        "is_first": torch.tensor([[True, False, False, False]]),
        "is_terminal": torch.zeros(1, 4, dtype=torch.bool),
    }
    out = model.loss(batch, torch.Generator().manual_seed(0))
    assert out.metrics["wm/decoder_loss"].item() < 3 * (symlog(torch.tensor(1e6)).item() + 3) ** 2


def test_the_actor_cannot_raise_its_return_by_predicting_termination(make_agent):
    """Constant reward -10 and a constant critic: the return depends on the policy only through
    the predicted continuation. As in DreamerV3's reference code the actor uses the continue
    head's mode without gradient, so it gets no gradient at all (a differentiable continuation
    would teach a driver that is losing ground to end episodes, e.g. by crashing, for free)."""
    config = make_agent(actor_entropy=0.0).config
    model = _world_model_with_constant_reward(config, -10.0)
    with torch.no_grad():  # continuation depends on the state, around 50 %
        model.continue_head.out.bias.zero_()
        model.continue_head.out.weight.normal_(0.0, 1.0)
    torch.manual_seed(1)
    behavior = Behavior(action_size=1, discrete=False, config=config)
    with torch.no_grad():
        for p in behavior.actor.net.out.parameters():
            p.normal_(0.0, 0.1)
    start = model.rssm.initial(64)
    start = Latent(start.h + 0.5 * torch.randn(64, config.deter), start.index, start.probs)
    out = behavior.losses(model, start, torch.ones(64), torch.Generator().manual_seed(2))
    assert 0.0 < out.metrics["imag/continue"].item() < 1.0, "the model predicts some terminations"
    out.actor_loss.backward()
    grads = [p.grad for p in behavior.actor.parameters() if p.grad is not None]
    assert grads and all(torch.count_nonzero(g) == 0 for g in grads)


def _episodes_of_six() -> dict[str, torch.Tensor]:
    """Two rows of two 6-step episodes (obs 3, action 2), each ending on a -50 terminal step."""
    k = torch.arange(12).remainder(6).float()
    return {
        "obs": torch.stack((k, torch.ones(12), -torch.ones(12)), -1).unsqueeze(0).repeat(2, 1, 1),
        "action": torch.zeros(2, 12, 2),
        "reward": torch.where(k == 5, -50.0, 1.0).unsqueeze(0).repeat(2, 1),
        "is_first": (k == 0).unsqueeze(0).repeat(2, 1),
        "is_terminal": (k == 5).unsqueeze(0).repeat(2, 1),
    }


def test_terminal_fit_metrics_measure_the_heads_on_the_steps_that_end_episodes(make_agent):
    """`wm/terminal_*` report the continue probability and the symlog reward error of the
    world model's own predictions on the terminal steps of the batch (and 0 without any)."""
    config = make_agent(obs_size=3).config
    torch.manual_seed(0)
    model = WorldModel(obs_size=3, action_size=2, config=config)
    with torch.no_grad():  # predictions that differ from step to step
        for head in (model.reward_head, model.continue_head):
            head.out.weight.normal_(0.0, 0.5)
    batch = _episodes_of_six()
    out = model.loss(batch, torch.Generator().manual_seed(0))
    terminal = batch["is_terminal"]
    with torch.no_grad():
        cont = model.continue_prob(out.observed.latent)[terminal]
        error = (symlog(model.reward(out.observed.latent)) - symlog(batch["reward"])).abs()[terminal]
    assert out.metrics["wm/terminal_steps"].item() == 4.0
    assert out.metrics["wm/terminal_continue"].item() == pytest.approx(cont.mean().item(), rel=1e-5)
    assert out.metrics["wm/terminal_reward_error"].item() == pytest.approx(error.mean().item(), rel=1e-5)
    assert error.mean().item() > 1.0  # an untrained model is far from the -50 penalty
    none = model.loss({**batch, "is_terminal": torch.zeros_like(terminal)}, torch.Generator().manual_seed(0))
    assert none.metrics["wm/terminal_steps"].item() == 0.0 and none.metrics["wm/terminal_continue"].item() == 0.0


def test_fused_imagination_matches_the_plain_formulation(make_agent, fill_random):
    """The fused readouts inside the imagination loop (actor, reward and critic first layers
    with gradient, the continue head without, the last state read without the actor) must give
    the rewards, continue flags, values and actor gradients of evaluating every head on every
    imagined state separately, as a dense layer on concat(h, straight-through one-hot z), with
    the actor reading each state through a stop-gradient (DreamerV3's actor(sg(s)))."""

    agent = make_agent(seed=3)
    fill_random(agent, 40)
    for _ in range(3):  # trained heads: zero-initialised output layers would hide mistakes
        agent.train_step()
    behavior, world_model = agent.behavior, agent.world_model
    batch = {k: torch.as_tensor(v) for k, v in agent.replay.sample(4, 8).items()}
    start = world_model.loss(batch, torch.Generator().manual_seed(0)).observed.latent.detach().reshape(-1)
    horizon, n = agent.config.imag_horizon, start.h.shape[0]
    actor_params = list(behavior.actor.parameters())

    imagined, reward, cont, values, critic_chunks = behavior._imagine(world_model, start, torch.Generator().manual_seed(5))
    critic_logits = torch.cat([logits for _, _, logits in critic_chunks])
    fused_grads = torch.autograd.grad(
        reward.sum() + values.sum() + imagined.extras["entropy"].sum(), actor_params, retain_graph=True
    )

    generator = torch.Generator().manual_seed(5)
    noise = iter(behavior.actor.noise((horizon, n), generator, start.h.device))
    classes = agent.config.classes

    def dense_mlp(mlp, state):
        weight = torch.cat((mlp.first.dense_weight, mlp.first.table.t()), 1)
        return mlp.finish(F.linear(state.dense(classes), weight))

    def policy(latent, first):
        assert first is None
        # actor(sg(s)): the explicit detach is the reference for the fused stop-gradient.
        action, entropy = behavior.actor.sample_from_output(dense_mlp(behavior.actor.net, latent.detach()), next(noise))
        return action, {"entropy": entropy}

    with frozen(world_model, behavior.critic):
        plain = world_model.rssm.imagine(policy, start, horizon, generator)
        states = plain.states
        plain_reward = torch.stack([world_model.twohot.mean(dense_mlp(world_model.reward_head, s)) for s in states[1:]])
        plain_cont = torch.stack([(dense_mlp(world_model.continue_head, s).squeeze(-1) > 0).float() for s in states[1:]])
        plain_values = torch.stack([behavior.twohot.mean(dense_mlp(behavior.critic, s)) for s in states])
    plain_grads = torch.autograd.grad(
        plain_reward.sum() + plain_values.sum() + plain.extras["entropy"].sum(), actor_params
    )
    assert torch.equal(torch.stack([s.index for s in imagined.states]), torch.stack([s.index for s in plain.states]))
    assert torch.allclose(reward, plain_reward, atol=1e-5)
    assert torch.equal(cont, plain_cont)
    assert torch.allclose(values, plain_values, atol=1e-5)
    for fused, reference in zip(fused_grads, plain_grads):
        assert reference.abs().sum() > 0
        assert torch.allclose(fused, reference, rtol=1e-4, atol=1e-6)

    # The critic's logits also carry its weight gradient, as the critic evaluated afresh on
    # detached states (every parameter, the first layer's weight and table included).
    critic_params = list(behavior.critic.parameters())
    detached = Latent.cat([s.detach() for s in imagined.states])
    reference_logits = dense_mlp(behavior.critic, detached)
    probe = torch.randn(critic_logits.shape, generator=torch.Generator().manual_seed(9))
    assert torch.allclose(critic_logits, reference_logits, atol=1e-5)
    merged = torch.autograd.grad((critic_logits * probe).sum(), critic_params)
    reference = torch.autograd.grad((reference_logits * probe).sum(), critic_params)
    for a, b in zip(merged, reference):
        assert b.abs().sum() > 0
        assert torch.allclose(a, b, rtol=1e-4, atol=1e-5)


def test_imagined_actions_have_no_gradient_through_the_actor_input(make_agent, fill_random):
    """DreamerV3 trains the actor on actor(sg(s)): in imagination each action depends on the
    actor's weights and its noise, never on the state through the actor's input. So the actions
    have no gradient with respect to the start state (h and the latent probabilities), while the
    rewards and values still do (through the dynamics), and d(actor loss)/d(actor) equals a plain
    autograd reference whose actor reads `.detach()`ed states. The old fused layer sent the
    actor's input gradient into h and the probabilities, which this test catches."""
    agent = make_agent(seed=4)
    fill_random(agent, 40)
    for _ in range(2):  # trained weights: zero-initialised output layers would hide the path
        agent.train_step()
    behavior, world_model = agent.behavior, agent.world_model
    batch = {k: torch.as_tensor(v) for k, v in agent.replay.sample(4, 8).items()}
    observed = world_model.loss(batch, torch.Generator().manual_seed(0)).observed.latent.reshape(-1)
    h = observed.h.detach().clone().requires_grad_(True)
    logits = torch.randn(*observed.index.shape, agent.config.classes, generator=torch.Generator().manual_seed(1))
    probs = torch.softmax(logits, -1).requires_grad_(True)  # any probabilities: only the path matters
    start = Latent(h, observed.index, probs)

    imagined, reward, cont, values, _ = behavior._imagine(world_model, start, torch.Generator().manual_seed(5))
    actions = imagined.actions
    assert actions.requires_grad  # gradient to the actor's weights
    # Each action alone, then all together: no path from the start state through the actor's input.
    for t in (0, actions.shape[0] - 1):
        grads = torch.autograd.grad(actions[t].sum(), [h, probs], retain_graph=True, allow_unused=True)
        for grad in grads:
            assert grad is None or torch.count_nonzero(grad) == 0, f"action {t} depends on the start state"
    probe = torch.randn(actions.shape, generator=torch.Generator().manual_seed(2))
    grads = torch.autograd.grad((actions * probe).sum() + imagined.extras["entropy"].sum(), [h, probs],
                                retain_graph=True, allow_unused=True)
    for grad in grads:
        assert grad is None or torch.count_nonzero(grad) == 0
    # The dynamics and the heads still carry the returns' gradient to the states.
    dynamics = torch.autograd.grad(reward.sum() + values.sum(), [h, probs], retain_graph=True)
    assert all(grad.abs().sum() > 0 for grad in dynamics)

    # The same rollout with the actor explicitly reading detached states through plain autograd
    # (no fused layer, every head on the dense straight-through features).
    horizon, n, classes = agent.config.imag_horizon, h.shape[0], agent.config.classes
    generator = torch.Generator().manual_seed(5)
    noise = iter(behavior.actor.noise((horizon, n), generator, h.device))

    def dense_mlp(mlp, state):
        weight = torch.cat((mlp.first.dense_weight, mlp.first.table.t()), 1)
        return mlp.finish(F.linear(state.dense(classes), weight))

    def policy(latent, first):
        assert first is None
        raw = dense_mlp(behavior.actor.net, Latent(latent.h.detach(), latent.index, None))
        action, entropy = behavior.actor.sample_from_output(raw, next(noise))
        return action, {"entropy": entropy}

    with frozen(world_model, behavior.critic):
        plain = world_model.rssm.imagine(policy, start, horizon, generator)
        plain_reward = torch.stack([world_model.twohot.mean(dense_mlp(world_model.reward_head, s)) for s in plain.states[1:]])
        plain_values = torch.stack([behavior.twohot.mean(dense_mlp(behavior.critic, s)) for s in plain.states])
    assert torch.equal(actions, plain.actions)
    actor_params = list(behavior.actor.parameters())
    weights = torch.linspace(0.5, 1.5, horizon).unsqueeze(-1)
    objective = (weights * (reward - values[:-1] + 0.1 * imagined.extras["entropy"])).sum()
    plain_objective = (weights * (plain_reward - plain_values[:-1] + 0.1 * plain.extras["entropy"])).sum()
    fused_grads = torch.autograd.grad(objective, actor_params)
    plain_grads = torch.autograd.grad(plain_objective, actor_params)
    for fused, reference in zip(fused_grads, plain_grads):
        assert reference.abs().sum() > 0
        assert torch.allclose(fused, reference, rtol=1e-4, atol=1e-6)


def test_a_known_action_cost_is_charged_exactly_in_imagination(make_agent):
    """`action_cost` w: each imagined action's reward is the reward head's minus w * ||a||, and
    that charge's gradient reaches the actor: with a constant reward head, the one thing the
    actor's loss can lower is the charge, so its gradient step shrinks the mean action (the
    same step without the charge moves it by nothing but the entropy bonus, which is off)."""
    torch.manual_seed(1)
    config = make_agent(actor_entropy=0.0).config

    def imagine(cost: float):
        c = config.model_copy(update={"action_cost": cost})
        model = _world_model_with_constant_reward(c, 1.0)
        torch.manual_seed(3)
        behavior = Behavior(action_size=1, discrete=False, config=c)
        with torch.no_grad():  # a policy that pushes one way, hard
            behavior.actor.net.out.bias.copy_(torch.tensor([2.0, 0.0]))
        start = model.rssm.initial(64)
        return model, behavior, start, behavior._imagine(model, start, torch.Generator().manual_seed(2))

    _, _, _, (plain, plain_reward, _, _, _) = imagine(0.0)
    model, behavior, start, (charged, charged_reward, _, _, _) = imagine(2.0)
    assert torch.allclose(plain.actions, charged.actions)
    expected = plain_reward - 2.0 * charged.actions.detach().norm(dim=-1)
    assert torch.allclose(charged_reward, expected, atol=1e-5)

    mean_before = behavior.actor.mode(start).mean().item()
    optimizer = torch.optim.SGD(behavior.actor.parameters(), lr=0.5)
    out = behavior.losses(model, start, torch.ones(64), torch.Generator().manual_seed(2))
    out.actor_loss.backward()
    optimizer.step()
    assert behavior.actor.mode(start).mean().item() < mean_before - 1e-3
