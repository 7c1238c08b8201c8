"""Caption rules of the motion prior on hand-made trajectories (a caption never contradicts
the motion that was measured)."""

from __future__ import annotations

import numpy as np
import pytest

from motionphysics.language.captions import GROUPS, HELD_OUT, NEUTRAL, TRAIN, caption_clip
from motionphysics.language.captions import motion_group as group_of
from motionphysics.priors.motion_data import motion_measures

T, DT = 16, 0.05
RNG = np.random.default_rng(0)
BODY = RNG.uniform(-0.1, 0.1, (300, 3))  # a 0.2 m blob of particles, centred


def _traj(centre_z, scale_xy=None, scale_z=None, rot=None, moving=0.0):
    """x [T, P, 3] from a centroid height path and per-frame axis scales (shape change)."""
    xs = []
    for i in range(T):
        p = BODY.copy()
        if rot is not None:
            a = rot[i]
            r = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
            p = p @ r.T
        if scale_xy is not None:
            p[:, :2] *= scale_xy[i]
        if scale_z is not None:
            p[:, 2] *= scale_z[i]
        p[:, 2] += centre_z[i] - p[:, 2].min() + 0.1 - 0.1  # bottom at centre_z
        xs.append(p)
    x = np.stack(xs)
    v = np.gradient(x, DT, axis=0)
    if moving:
        v[-4:] += moving
    return {"x": x, "v": v, "t": np.arange(T) * DT}


def _fall_then(after):
    """Bottom height: falls 0.3 m in 5 frames, then ``after`` (list of T-5 heights)."""
    fall = 0.3 * (1 - (np.arange(5) / 5.0) ** 2)
    return np.concatenate([fall, after])


def _group(traj, granular=False):
    m = motion_measures(traj)
    m["granular"] = float(granular)
    return group_of(m), m


def test_rigid_high_bounce():
    up = 0.2 * np.sin(np.linspace(0, np.pi, 11))
    g, m = _group(_traj(_fall_then(up)))
    assert m["rebound"] > 0.5 and m["max_deform"] < 1e-6
    assert g == "bounces_high"


def test_rigid_small_hop_barely_bounces():
    up = 0.045 * np.sin(np.linspace(0, np.pi, 11))
    g, m = _group(_traj(_fall_then(up)))
    assert 0.06 < m["rebound"] < 0.3
    assert g == "barely_bounces"


def test_rigid_landing_keeps_shape():
    g, _ = _group(_traj(_fall_then(np.zeros(11))))
    assert g == "keeps_shape"


def test_tumbling_rigid_object_is_not_squashed():
    """Rotation changes the vertical extent; the rotation-invariant deformation must not."""
    rot = np.linspace(0, 1.2, T)
    g, m = _group(_traj(_fall_then(np.zeros(11)), rot=rot))
    assert m["max_deform"] < 1e-6
    assert g == "keeps_shape"


def test_permanent_flattening_squashes_flat():
    sz = np.concatenate([np.ones(5), np.full(11, 0.55)])
    sxy = 1 / np.sqrt(sz)
    g, m = _group(_traj(_fall_then(np.zeros(11)), scale_xy=sxy, scale_z=sz))
    assert m["deform"] > 0.06 and m["spread"] < 1.5
    assert g == "squashes_flat"


def test_decaying_oscillation_wobbles():
    k = np.arange(11)
    sz = np.concatenate([np.ones(5), 1 - 0.25 * np.cos(k * 1.6) * np.exp(-k / 6) * (k > 0)])
    sz[5] = 0.75
    g, m = _group(_traj(_fall_then(np.zeros(11)), scale_xy=1 / np.sqrt(sz), scale_z=sz))
    assert m["wobble"] >= 2 and m["deform"] < 0.05
    assert g == "wobbles"


def test_fast_wide_spread_splashes():
    k = np.arange(11)
    sz = np.concatenate([np.ones(5), np.maximum(0.12, 1 - k / 3)])
    sxy = np.concatenate([np.ones(5), np.minimum(3.0, 1 + k)])
    g, m = _group(_traj(_fall_then(np.zeros(11)), scale_xy=sxy, scale_z=sz))
    assert m["max_spread"] > 2 and m["min_height"] < 0.35
    assert g == "splashes"


def test_slow_moderate_spread_still_moving_oozes():
    k = np.arange(11)
    sz = np.concatenate([np.ones(5), 1 - 0.055 * k])
    sxy = np.concatenate([np.ones(5), 1 + 0.07 * k])
    g, m = _group(_traj(_fall_then(np.zeros(11)), scale_xy=sxy, scale_z=sz), granular=False)
    assert 1.5 < m["spread"] < 1.9 and m["late_speed"] > 0.01
    assert g == "oozes"
    # the same motion of sand that has not come to rest is not called a heap
    g2, _ = _group(_traj(_fall_then(np.zeros(11)), scale_xy=sxy, scale_z=sz, moving=0.2), True)
    assert g2 is None


def test_granular_collapse_at_rest_crumbles():
    k = np.arange(11)
    sz = np.concatenate([np.ones(5), np.maximum(0.4, 1 - 0.3 * k)])
    sxy = np.concatenate([np.ones(5), np.minimum(1.6, 1 + 0.3 * k)])
    traj = _traj(_fall_then(np.zeros(11)), scale_xy=sxy, scale_z=sz)
    traj["v"][-5:] = 0.0  # at rest
    assert _group(traj, granular=True)[0] == "crumbles"
    # a liquid doing the same is never called a heap
    assert _group(traj, granular=False)[0] != "crumbles"


def test_phrasing_sets_are_disjoint_and_cover_every_group():
    assert set(TRAIN) == set(HELD_OUT) == set(GROUPS)
    train = {p for v in TRAIN.values() for p in v}
    held = {p for v in HELD_OUT.values() for p in v}
    assert not train & held
    assert not (train | held) & set(NEUTRAL)


@pytest.mark.parametrize("held_out", [False, True])
def test_caption_uses_only_its_groups_phrases(held_out):
    from motionphysics.language.captions import training_phrasings

    table = HELD_OUT if held_out else {g: training_phrasings(g) for g in GROUPS}
    up = 0.2 * np.sin(np.linspace(0, np.pi, 11))
    m = motion_measures(_traj(_fall_then(up)))
    rng = np.random.default_rng(3)
    for _ in range(40):
        text, g = caption_clip(m, "elastic", "sphere", rng, held_out=held_out)
        assert g == "bounces_high"
        assert any(text.endswith(p) for p in table["bounces_high"])
        others = [p for k, v in table.items() if k != "bounces_high" for p in v]
        assert not any(text.endswith(p) for p in others)
    # a clip no rule fits gets a neutral phrase (no motion claim)
    m_none = dict(m, rebound=0.32, deform=0.055)  # between bounce classes and squash
    text, g = caption_clip(m_none, "elastic", "sphere", rng)
    assert g is None and any(text.endswith(p) for p in NEUTRAL)


@pytest.mark.parametrize(
    ("prompt", "group", "negative"),
    [
        (
            "A stiff ring is dropped, stays rigid and bounces high off the ground",
            "bounces_high",
            "A stiff ring squashes and stays flat",
        ),
        # a wobble sits between "too stiff" and "too soft": the unconditional prompt
        ("A soft rubber duck is dropped, squashes and wobbles", "wobbles", ""),
        ("a ring shakes and jiggles like gelatin", "wobbles", ""),
        ("Thick honey oozes slowly over the floor", "oozes", "Thick honey splashes and spreads"),
        ("Thin runny water splashes and spreads thin", "splashes", "Thin runny water oozes slowly"),
        ("A sand castle crumbles into a heap", "crumbles", "A sand castle keeps its shape"),
        # keeping its shape is contrasted with losing it for good (not with a wobble)
        (
            "A hard clay ball is dropped and keeps its shape when it lands",
            "keeps_shape",
            "A hard clay ball squashes and stays flat",
        ),
        ("A rubber duck hits the ground and bounces back", "bounces_high", None),
        # no motion claim: nothing to contrast with
        ("A rubber duck", None, ""),
        ("A metal rod is dropped on the floor", None, ""),
    ],
)
def test_contrast_prompt_is_the_opposite_motion_with_the_same_subject(prompt, group, negative):
    from motionphysics.language.captions import OPPOSITE, contrast_prompt, prompt_motion_group

    assert prompt_motion_group(prompt)[0] == group
    neg = contrast_prompt(prompt)
    if negative is not None:
        assert neg == negative
    if group is not None and OPPOSITE[group] is not None:
        assert neg.endswith(TRAIN[OPPOSITE[group]][0])
        assert prompt_motion_group(neg)[0] == OPPOSITE[group]  # the contrast is a claim too


@pytest.mark.parametrize(
    ("prompt", "side", "negative"),
    [
        (
            "A ring of coarse, rough gravel is dropped and stays a tall, steep heap",
            "steep",
            "A ring of coarse, rough gravel splashes and spreads",
        ),
        ("A lump of damp sand crumbles but stays a steep pile", "steep", None),
        (
            "A ring of fine, dry sand is dropped, collapses and spreads out flat",
            "flat",
            "A ring of fine, dry sand keeps its shape",
        ),
        # "a heap", "a mound", "a pile": what every crumbling pile does, neither side
        ("A sand castle crumbles into a heap", None, "A sand castle keeps its shape"),
        ("a ring disintegrates into a pile", None, "a ring keeps its shape"),
        ("A sandcastle falls apart into a mound", None, None),
        ("a block of sand crumbles and settles in a heap", None, None),
    ],
)
def test_a_pile_asked_to_stay_steep_is_contrasted_with_a_flat_spread(prompt, side, negative):
    """Every pile "crumbles"; against "keeps its shape" a prompt asking for a tall, steep
    heap was pushed to collapse like one asking for a flat spread. Its opposite is a flat
    spread; a flat spread's, and a plain heap's, is still keeping its shape."""
    from motionphysics.language.captions import contrast_prompt, heap_side, prompt_motion_group

    assert prompt_motion_group(prompt)[0] == "crumbles"
    assert heap_side(prompt) == side
    neg = contrast_prompt(prompt)
    if negative is not None:
        assert neg == negative
    assert prompt_motion_group(neg)[0] == ("splashes" if side == "steep" else "keeps_shape")


def test_opposites_pair_up_the_groups():
    from motionphysics.language.captions import OPPOSITE

    assert set(OPPOSITE) == set(GROUPS) and set(OPPOSITE.values()) <= {*GROUPS, None}
    assert all(OPPOSITE[g] != g for g in GROUPS)
    assert OPPOSITE["wobbles"] is None
    for a, b in (("bounces_high", "squashes_flat"), ("splashes", "oozes")):
        assert OPPOSITE[a] == b and OPPOSITE[b] == a


def test_a_solid_is_called_stiff_or_soft_by_how_far_it_gave_on_impact():
    """The firmness word follows the measured peak deformation, never the rebound: a hard
    and a soft bounce rebound alike, and only the soft one may be called soft."""
    from motionphysics.language.captions import FIRMNESS, SOFT_MAX_DEFORM, STIFF_MAX_DEFORM

    up = 0.2 * np.sin(np.linspace(0, np.pi, 11))
    bounce = motion_measures(_traj(_fall_then(up)))
    hard = dict(bounce, max_deform=0.5 * STIFF_MAX_DEFORM)
    soft = dict(bounce, max_deform=SOFT_MAX_DEFORM + 0.02, deform=0.01)
    mid = dict(bounce, max_deform=0.5 * (STIFF_MAX_DEFORM + SOFT_MAX_DEFORM))
    splash = dict(bounce, spread=2.5, max_spread=2.6, min_height=0.1, final_height=0.1,
                  deform=0.5, max_deform=0.5)  # fmt: skip

    def words(m, cls="elastic", n=60, **kw):
        rng = np.random.default_rng(7)
        out = [caption_clip(m, cls, "sphere", rng, **kw) for _ in range(n)]
        return [t.lower().split() for t, _ in out], {g for _, g in out}

    hard_w, g_hard = words(hard)
    soft_w, g_soft = words(soft)
    assert g_hard == g_soft == {"bounces_high"}  # same motion group either way
    stiff_set, soft_set = set(FIRMNESS["stiff"]), set(FIRMNESS["soft"])
    n_stiff = sum(bool(stiff_set & set(w)) for w in hard_w)
    n_soft = sum(bool(soft_set & set(w)) for w in soft_w)
    assert 0.25 * 60 < n_stiff < 0.75 * 60 and 0.25 * 60 < n_soft < 0.75 * 60  # about half
    assert not any(soft_set & set(w) for w in hard_w)
    assert not any(stiff_set & set(w) for w in soft_w)
    # between the bounds, a flow, and with_firmness=False: no firmness word at all
    for m, cls, kw in (
        (mid, "elastic", {}),
        (splash, "newtonian", {}),
        (hard, "elastic", {"with_firmness": False}),
    ):
        ws, _ = words(m, cls, **kw)
        assert not any((stiff_set | soft_set) & set(w) for w in ws)


@pytest.mark.parametrize(
    "prompt, group",
    [
        # an event clause ("hits the ground") is no motion claim: the motion clause decides
        ("A super ball hits the ground and leaps back up", "bounces_high"),
        ("A rigid wooden block hits the floor and stays the same", "keeps_shape"),
        ("A soft metal rod bends permanently when it hits the ground", "squashes_flat"),
        # "but" splits clauses like "and"
        ("The stone statue falls over but stays intact", "keeps_shape"),
        # verbs beyond the phrasings' first words, and an adverb before the verb
        ("Honey drips slowly", "oozes"),
        ("Cold honey trickles slowly down", "oozes"),
        ("The bouncy ball springs off the floor", "bounces_high"),
        ("A rubber toy falls and bounces several times", "bounces_high"),
        # still no claim: an event alone
        ("A metal rod is dropped on the floor", None),
        ("A ball hits the ground", None),
    ],
)
def test_the_motion_reading_skips_event_clauses_and_finds_more_verbs(prompt, group):
    from motionphysics.language.captions import prompt_motion_group

    assert prompt_motion_group(prompt)[0] == group


def test_paraphrases_are_new_and_keep_the_held_out_words_unseen():
    """The training captions' paraphrases repeat no phrasing and none of the distinctive
    words of the held-out phrasings the discrimination is measured with."""
    from motionphysics.language.captions import PARAPHRASES, READING_EXTRA, training_phrasings

    assert set(PARAPHRASES) == set(GROUPS)
    every = [p for g in GROUPS for p in training_phrasings(g)]
    assert len(set(every)) == len(every)
    assert not set(every) & {p for g in GROUPS for p in (*HELD_OUT[g], *READING_EXTRA[g])}
    unseen = ("feebl", "tiny bit", "gelatin", "trembl", "splatter", "spill", "syrup", "goo",
              "holds its form", "perfectly", "disintegrat", "pieces", "flattened", "deforms")  # fmt: skip
    for p in every:
        assert not any(w in p for w in unseen), p
    for g in GROUPS:
        assert len(training_phrasings(g)) >= 11


def test_reading_phrasings_never_caption_a_training_clip():
    from motionphysics.language.captions import READING_EXTRA, READING_NEUTRAL

    assert set(READING_EXTRA) == set(GROUPS)
    captions = {p for g in GROUPS for p in (*TRAIN[g], *HELD_OUT[g])}
    extras = [p for g in GROUPS for p in READING_EXTRA[g]]
    assert len(set(extras)) == len(extras) and not captions & set(extras)
    assert not captions & set(READING_NEUTRAL)


def test_a_reading_can_leave_out_a_group_the_material_cannot_show():
    from motionphysics.language.captions import prompt_motion_group

    prompt = "A block of water collapses and splashes across the floor of a tank."
    assert prompt_motion_group(prompt)[0] == "crumbles"
    group, sim = prompt_motion_group(prompt, exclude=("crumbles",))
    assert group == "splashes" and sim > 0.6
    assert prompt_motion_group("A column of sand collapses into a heap.", ("crumbles",))[0] is None
