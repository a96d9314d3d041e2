"""World models as plain data: the sizes that rebuild them, for self-describing checkpoints.

``describe_*`` reads a model's sizes into a dict of numbers and strings (what
``torch.load(..., weights_only=True)`` reads back without unpickling objects);
``build_*`` constructs an untrained model from that dict. ``describe_*`` rebuilds the
model once and compares every parameter and buffer shape and every submodule's type, so a
model it cannot describe (a custom dynamics, another activation) is refused when saving,
not discovered when a deployment fails to load it.
"""

from __future__ import annotations

from torch import nn

from simdist.modules import (RSSM, DreamerWorldModel, MLPDynamics, PixelDecoder, PixelEncoder,
                             ReadoutEncoder, StateReadout,
                             ScalarHead, SimDistWorldModel, StateDecoder, StateEncoder)


def _linears(module: nn.Module) -> list[nn.Linear]:
    return [m for m in module.modules() if isinstance(m, nn.Linear)]


def _structure(model: nn.Module) -> tuple[dict, list]:
    shapes = {k: (tuple(v.shape), v.dtype) for k, v in model.state_dict().items()}
    return shapes, [(name, type(m).__name__) for name, m in model.named_modules()]


def _check_rebuilds(model: nn.Module, rebuilt: nn.Module, what: str) -> None:
    (shapes, types), (shapes2, types2) = _structure(model), _structure(rebuilt)
    if shapes != shapes2 or types != types2:
        differ = sorted(set(shapes.items()) ^ set(shapes2.items()), key=str)[:3] or \
            [a for a, b in zip(types, types2) if a != b][:3] or ["number of submodules"]
        raise TypeError(f"this {what} is not one the checkpoint format can describe (built "
                        f"other than by its constructors; first differences: {differ}); save "
                        "its state_dict() and the code that builds it instead")


def describe_simdist_model(model: SimDistWorldModel) -> dict:
    """The sizes of a :class:`~simdist.modules.SimDistWorldModel` built by ``build``.

    Raises:
        TypeError: the model has a swapped-in dynamics or other parts ``build`` would not
            make.

    Examples:
        >>> wm = SimDistWorldModel.build(obs_dim=10, action_dim=3, size="tiny")
        >>> desc = describe_simdist_model(wm)
        >>> desc["latent_dim"], desc["history"], type(build_simdist_model(desc)).__name__
        (16, 2, 'SimDistWorldModel')
    """
    if type(model.dynamics) is not MLPDynamics:
        raise TypeError(f"the checkpoint format describes MLPDynamics only, got "
                        f"{type(model.dynamics).__name__}; save world_model.state_dict() and "
                        "the code that builds it instead")
    enc = model.encoder
    desc = {"type": "SimDistWorldModel", "obs_dim": int(enc.obs_dim),
            "action_dim": int(model.action_dim), "latent_dim": int(enc.latent_dim),
            "hidden": int(_linears(enc.net)[0].out_features), "history": int(enc.history),
            "simnorm_groups": enc.simnorm_groups}
    if enc.ignored_inputs:  # files written before the option stay readable without it
        desc["ignored_inputs"] = list(enc.ignored_inputs)
    if enc.action_dim:  # likewise; code that predates it refuses the file (shape mismatch)
        desc["previous_action"] = True
    prior = model.policy_head
    if getattr(prior, "action_low", None) is not None:  # likewise: files without it: [-1, 1]
        desc["prior_bounds"] = [prior.action_low.tolist(), prior.action_high.tolist()]
    if model.dynamics.residual != "additive":  # likewise: files without it are additive
        desc["dynamics_residual"] = model.dynamics.residual
    dynamics_hidden = int(_linears(model.dynamics.net)[0].out_features)
    if dynamics_hidden != desc["hidden"]:  # likewise: written only when it differs
        desc["dynamics_hidden"] = dynamics_hidden
    _check_rebuilds(model, build_simdist_model(desc), "SimDistWorldModel")
    return desc


def build_simdist_model(desc: dict) -> SimDistWorldModel:
    """An untrained :class:`~simdist.modules.SimDistWorldModel` of the described sizes."""
    return SimDistWorldModel.build(
        desc["obs_dim"], desc["action_dim"], size="small", latent_dim=desc["latent_dim"],
        hidden=desc["hidden"], history=desc["history"], simnorm_groups=desc["simnorm_groups"],
        ignored_inputs=desc.get("ignored_inputs", ()),
        dynamics_hidden=desc.get("dynamics_hidden"),
        previous_action=bool(desc.get("previous_action", False)),
        dynamics_residual=desc.get("dynamics_residual", "additive"),
        prior_bounds=desc.get("prior_bounds"))


def _describe_encoder(encoder: nn.Module) -> dict:
    if isinstance(encoder, StateEncoder):
        linears = _linears(encoder.net)
        return {"kind": "state", "state_dim": int(encoder.state_dim),
                "embed_dim": int(encoder.embed_dim), "hidden": int(linears[0].out_features),
                "layers": len(linears)}
    if isinstance(encoder, PixelEncoder):
        desc = {"kind": "pixels", "depth": int(encoder.net[0].out_channels),
                "norm": encoder.norm, "input_norm": encoder.input_norm,
                "image_size": int(encoder.image_size)}
        if encoder.arch != "dreamer":  # older files, written before arch, stay readable
            desc.update(arch=encoder.arch, keypoints=int(encoder.keypoints),
                        depth=int(encoder.net[0].out_channels) // 2)
        return desc
    if isinstance(encoder, ReadoutEncoder):  # a frozen readout before a state encoder
        return {"kind": "readout", "readout": encoder.readout.describe(),
                "state": _describe_encoder(encoder.encoder)}
    raise TypeError(f"the checkpoint format describes StateEncoder, PixelEncoder and "
                    f"ReadoutEncoder, got "
                    f"{type(encoder).__name__}")


def _build_encoder(desc: dict) -> nn.Module:
    if desc["kind"] == "state":
        return StateEncoder(desc["state_dim"], desc["embed_dim"], desc["hidden"], desc["layers"])
    if desc["kind"] == "pixels":
        return PixelEncoder(desc["depth"], desc["image_size"], desc["norm"], desc["input_norm"],
                            desc.get("arch", "dreamer"), desc.get("keypoints", 32))
    if desc["kind"] == "readout":
        return ReadoutEncoder(StateReadout.from_description(desc["readout"]),
                              _build_encoder(desc["state"]))
    raise ValueError(f"unknown encoder kind {desc['kind']!r}")


def _describe_head(head: nn.Module | None) -> dict | None:
    if head is None:
        return None
    if isinstance(head, ScalarHead):
        linears = _linears(head.net)
        return {"kind": "scalar", "hidden": int(linears[0].out_features),
                "layers": len(linears) - 1}
    if isinstance(head, StateDecoder):
        linears = _linears(head.net)
        return {"kind": "state", "state_dim": int(linears[-1].out_features),
                "hidden": int(linears[0].out_features), "layers": len(linears) - 1}
    if isinstance(head, PixelDecoder):
        return {"kind": "pixels", "depth": int(head.depth)}
    raise TypeError(f"the checkpoint format describes ScalarHead, StateDecoder and "
                    f"PixelDecoder heads, got {type(head).__name__}")


def _build_head(desc: dict | None, feature_dim: int) -> nn.Module | None:
    if desc is None:
        return None
    if desc["kind"] == "scalar":
        return ScalarHead(feature_dim, desc["hidden"], desc["layers"])
    if desc["kind"] == "state":
        return StateDecoder(feature_dim, desc["state_dim"], desc["hidden"], desc["layers"])
    if desc["kind"] == "pixels":
        return PixelDecoder(feature_dim, desc["depth"])
    raise ValueError(f"unknown head kind {desc['kind']!r}")


def describe_dreamer_model(model: DreamerWorldModel) -> dict:
    """The parts and sizes of a :class:`~simdist.modules.DreamerWorldModel` (teacher,
    student or pixel Dreamer, any size row or encoder options).

    Examples:
        >>> student = DreamerWorldModel.student(action_dim=1, size="tiny", norm="layer")
        >>> desc = describe_dreamer_model(student)
        >>> desc["encoder"]["kind"], desc["encoder"]["norm"], desc["decoder"]
        ('pixels', 'layer', None)
        >>> build_dreamer_model(desc).rssm.deter_dim
        32
    """
    rssm = model.rssm
    desc = {"type": "DreamerWorldModel", "action_dim": int(rssm.action_dim),
            "encoder": _describe_encoder(model.encoder),
            "rssm": {"deter_dim": int(rssm.deter_dim), "stoch": int(rssm.stoch),
                     "classes": int(rssm.classes),
                     "hidden_dim": int(rssm.input_net[0].out_features),
                     "unimix": float(rssm.unimix)},
            "decoder": _describe_head(model.decoder),
            "reward_head": _describe_head(model.reward_head),
            "continue_head": _describe_head(model.continue_head)}
    _check_rebuilds(model, build_dreamer_model(desc), "DreamerWorldModel")
    return desc


def build_dreamer_model(desc: dict) -> DreamerWorldModel:
    """An untrained :class:`~simdist.modules.DreamerWorldModel` of the described parts."""
    encoder = _build_encoder(desc["encoder"])
    r = desc["rssm"]
    rssm = RSSM(encoder.embed_dim, desc["action_dim"], r["deter_dim"], r["stoch"],
                r["classes"], r["hidden_dim"], r["unimix"])
    feature_dim = rssm.feature_dim
    return DreamerWorldModel(encoder, rssm, _build_head(desc["decoder"], feature_dim),
                             _build_head(desc["reward_head"], feature_dim),
                             _build_head(desc["continue_head"], feature_dim))
