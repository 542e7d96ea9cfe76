"""Stiffness model: beam compliances, K symmetric positive definite, FE agreement (Table 2), compensation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from planner.core.description import Section
from planner.core.exceptions import DeflectionNotCompensated, InvalidRobotDescription
from planner.core.so3 import pose_error
from planner.dynamics.beams import (
    beam_compliance,
    beam_frame,
    deflected_pose,
    map_compliance,
    section_properties,
)
from planner.dynamics.frame_fe import element_stiffness, fe_deflection
from planner.dynamics.load_change import load_change
from planner.dynamics.payload import RigidPayload, box_inertia
from planner.dynamics.stiffness import LoadCase, StiffnessModel, compensate_goal
from planner.kinematics.closed_form import redundant_family
from planner.robots.cabin8 import Cabin8, default_description_path
from tests.conftest import admissible_joints

E, G = 206e9, 79.4e9
PAYLOAD = RigidPayload(100.0, np.array([0.0, 0.0, 0.25]), box_inertia(100.0, (0.45, 0.35, 0.30)))
GRASP = np.eye(4)
GRASP[:3, 3] = [0.0, 0.0, 0.20]


@pytest.fixture(scope="module")
def model(robot: Cabin8) -> StiffnessModel:
    return StiffnessModel(robot)


@pytest.fixture(scope="module")
def samples(robot: Cabin8) -> np.ndarray:
    return admissible_joints(robot, 50, seed=7)


# --------------------------------------------------------------------------------------------- beams
def test_beam_compliance_is_the_closed_form_cantilever() -> None:
    """Eq. (54) entries are the textbook cantilever results for a 0.4 m AB link (b = 0.06, h = 0.03)."""
    sec = Section(b=0.06, h=0.03)
    L = 0.4
    C = beam_compliance(L, sec, E, G)
    Iz, Iy = 0.06 * 0.03**3 / 12, 0.06**3 * 0.03 / 12
    J = 0.06 * 0.03**3 * (1 / 3 - 0.21 * 0.5)
    F = 100.0
    # Tip load F_y: deflection F L^3 / 3EI_z, slope F L^2 / 2EI_z; tip moment M_z: slope M L / EI_z.
    assert C[1, 1] * F == pytest.approx(F * L**3 / (3 * E * Iz), rel=1e-12)
    assert C[5, 1] * F == pytest.approx(F * L**2 / (2 * E * Iz), rel=1e-12)
    assert C[5, 5] == pytest.approx(L / (E * Iz), rel=1e-12)
    # F_z bends about y the other way (right-handed frame): the slope is negative.
    assert C[2, 2] == pytest.approx(L**3 / (3 * E * Iy), rel=1e-12)
    assert C[4, 2] == pytest.approx(-(L**2) / (2 * E * Iy), rel=1e-12)
    assert C[0, 0] == pytest.approx(L / (E * 0.06 * 0.03), rel=1e-12)
    assert C[3, 3] == pytest.approx(L / (G * J), rel=1e-12)
    assert section_properties(sec)[3] == pytest.approx(J, rel=1e-12)
    # A numeric feel: 100 N across the thin side of AB bends its tip by about 0.077 mm.
    assert C[1, 1] * F == pytest.approx(0.0767e-3, rel=2e-3)


@pytest.mark.parametrize("name", ["link_ab", "link_ef", "platform", "column", "arm", "slide"])
def test_beam_compliance_matches_the_clamped_fe_element(robot: Cabin8, name: str) -> None:
    """An oblique beam: eq. (54) rotated to base axes = inverse of the FE element's free-end block."""
    sec = getattr(robot.desc.stiffness.sections, name)
    rng = np.random.default_rng(abs(hash(name)) % 2**32)
    p0, p1 = rng.normal(size=3), rng.normal(size=3)
    p1 = p0 + 0.5 * (p1 - p0) / np.linalg.norm(p1 - p0)
    z_ref = rng.normal(size=3)
    R, length = beam_frame(p0[None], p1[None], z_ref[None])
    C = map_compliance(beam_compliance(length, sec, E, G), R, p1[None], p1[None])[0]
    K_fe = element_stiffness(p0, p1, z_ref, sec, E, G)
    C_fe = np.linalg.inv(K_fe[6:, 6:])  # node 0 clamped
    np.testing.assert_allclose(C, C_fe, rtol=1e-9, atol=1e-12 * np.abs(C).max())
    # The free element is singular exactly along the six rigid-body motions.
    assert np.sum(np.linalg.eigvalsh(K_fe) < 1e-9 * np.abs(K_fe).max()) == 6


# ------------------------------------------------------------------------------------- Cartesian K
def test_stiffness_is_symmetric_positive_definite(model: StiffnessModel, samples: np.ndarray) -> None:
    for T in (None, GRASP):
        K = model.stiffness(samples, T)
        C = model.compliance(samples, T)
        np.testing.assert_allclose(K, np.swapaxes(K, 1, 2), rtol=0, atol=1e-9 * np.abs(K).max())
        assert np.all(np.linalg.eigvalsh(K) > 0)
        eye = np.broadcast_to(np.eye(6), K.shape)
        np.testing.assert_allclose(K @ C, eye, atol=1e-7)


def test_compliance_moves_between_frames_as_a_rigid_body(model: StiffnessModel, samples: np.ndarray) -> None:
    """Payload-frame compliance = the tool-frame compliance seen through the rigid grasp offset."""
    from planner.dynamics.beams import twist_transfer

    Ct = model.compliance(samples)
    Cp = model.compliance(samples, GRASP)
    T_tool = model.robot.frames(samples)[:, 6]
    d = np.einsum("nij,j->ni", T_tool[:, :3, :3], GRASP[:3, 3])
    J = twist_transfer(d)
    np.testing.assert_allclose(Cp, J @ Ct @ np.swapaxes(J, 1, 2), rtol=1e-9, atol=1e-16)


def test_stage_with_rigid_links_is_the_sliders_through_the_stage_jacobian(
    robot: Cabin8, samples: np.ndarray, tmp_path: Path
) -> None:
    """With links 1e8 times stiffer and rigid pins, the stage's in-plane compliance is J_1 diag(1/k) J_1^T.

    J_1 = d(x, y, gamma)/d(x1, x2, x3) is the paper's parallel-stage Jacobian (eq. 24-25, CasADi AD): the
    pins and the branch assembly must reproduce the kinematics exactly in this limit.
    """

    def stiff(raw: dict) -> None:
        raw["stiffness"].update(E_Pa=206e17, G_Pa=79.4e17, pin_compliance_m_N=0.0)

    rigid = Cabin8(_write(tmp_path, stiff))
    C = np.linalg.inv(StiffnessModel(rigid).stage_stiffness(samples))[:, [0, 1, 5]][:, :, [0, 1, 5]]
    k = robot.desc.stiffness.drive_stiffness()[1:4]
    for i, q in enumerate(samples):
        J1 = robot.stage_jacobian(q)
        np.testing.assert_allclose(
            C[i], J1 @ np.diag(1.0 / k) @ J1.T, rtol=1e-5, atol=1e-12 * np.abs(C[i]).max()
        )
    # With the real links the stage is softer than the sliders alone, in every direction of the plane.
    K_real = StiffnessModel(robot).stage_stiffness(samples)[:, [0, 1, 5]][:, :, [0, 1, 5]]
    K_rigid = np.linalg.inv(C)
    assert np.all(np.linalg.eigvalsh(K_rigid - K_real) > -1e-6 * np.abs(K_rigid).max())
    assert np.all(np.linalg.eigvalsh(StiffnessModel(robot).stage_stiffness(samples)) > 0)


def test_gravity_does_positive_work(model: StiffnessModel, samples: np.ndarray) -> None:
    """A force at the frame origin moves the point along itself: f . delta = f^T C f > 0."""
    rng = np.random.default_rng(3)
    w = np.concatenate([rng.normal(size=(50, 3)) * 500, np.zeros((50, 3))], axis=1)
    x = model.deflections(samples, LoadCase(None, GRASP, w, gravity=False))
    assert np.all(np.einsum("ni,ni->n", w, x) > 0)
    # A heavy payload sags: its frame goes down (gravity is -y).
    xg = model.deflections(samples, LoadCase(PAYLOAD, GRASP))
    assert np.all(xg[:, 1] < 0)


# --------------------------------------------------------------------------------------- FE agreement
def test_fe_route_agrees_like_table2(robot: Cabin8, model: StiffnessModel, samples: np.ndarray) -> None:
    """50 random configurations and 6-D loads (0-1000 N, 0-1 N m, as section 5.2): FE and analytical agree.

    The paper accepts 15% per axis; on end loads the two routes solve the same Euler-Bernoulli model
    exactly, so they agree to round-off.
    """
    rng = np.random.default_rng(11)
    wrenches = np.concatenate([rng.uniform(0, 1000, (50, 3)), rng.uniform(0, 1, (50, 3))], axis=1)
    an = model.deflections(samples, LoadCase(None, GRASP, wrenches, gravity=False))
    fe = np.array(
        [
            fe_deflection(robot, q, T_tool_frame=GRASP, wrench=w, gravity=False)
            for q, w in zip(samples, wrenches, strict=True)
        ]
    )
    scale = np.linalg.norm(fe[:, :3], axis=1, keepdims=True)
    assert np.all(np.abs(an[:, :3] - fe[:, :3]) <= 0.15 * np.maximum(np.abs(fe[:, :3]), 0.01 * scale))
    rel = np.linalg.norm(an - fe, axis=1) / np.linalg.norm(fe, axis=1)
    assert rel.max() < 1e-8
    # The deflections are those of a real load case (with the paper-fit data 0.05 mm and up; near stage
    # singularities the stage is soft).
    assert 1e-5 < scale.min() and scale.max() < 0.1


def test_fe_route_bounds_the_gravity_lumping(
    robot: Cabin8, model: StiffnessModel, samples: np.ndarray
) -> None:
    """Under gravity the analytical route lumps the stage links at the platform centre: still within 15%."""
    an = model.deflections(samples[:20], LoadCase(PAYLOAD, GRASP))
    fe = np.array([fe_deflection(robot, q, PAYLOAD, GRASP) for q in samples[:20]])
    rel = np.linalg.norm(an[:, :3] - fe[:, :3], axis=1) / np.linalg.norm(fe[:, :3], axis=1)
    assert rel.max() < 0.15
    assert rel.max() < 0.02  # measured: below 0.5%


def test_the_load_change_is_the_payload_weight_as_a_wrench_and_the_thin_forms_agree(
    robot: Cabin8, model: StiffnessModel, samples: np.ndarray
) -> None:
    """Attaching the payload moves the frame by the deflection under its weight alone (superposition).

    An independent route: the payload's weight m g at its centre of mass, moved to the frame origin as a
    wrench (f, (c - p) x f), with gravity off; and the thin forms give the load case's numbers.
    """
    q = samples[:12]
    T_frame = robot.fk_batch(q) @ GRASP
    com = (robot.fk_batch(q) @ np.append(PAYLOAD.com_tool, 1.0))[:, :3]
    f = np.broadcast_to(PAYLOAD.mass * np.asarray(robot.desc.gravity_m_s2), (len(q), 3))
    wrench = np.concatenate([f, np.cross(com - T_frame[:, :3, 3], f)], axis=1)
    direct = model.deflections(q, LoadCase(None, GRASP, wrench, gravity=False))
    grasp = np.array([load_change(robot, qi, None, PAYLOAD, GRASP).jump for qi in q])
    assert np.max(np.abs(grasp - direct)) <= 1e-12 * np.max(np.abs(direct))
    assert np.all(grasp[:, 1] < 0)  # a payload pulls the frame down (gravity -y); a release springs it up
    release = load_change(robot, q[3], PAYLOAD, None, GRASP).jump
    assert np.array_equal(release, -grasp[3])
    with_payload = model.deflections(q, LoadCase(PAYLOAD, GRASP))
    assert np.array_equal(model.deflection(q[3], PAYLOAD, GRASP).twist, with_payload[3])
    assert np.array_equal(model.deflection_along(q, PAYLOAD, GRASP), with_payload)


def test_deflection_along_is_the_pointwise_deflection(model: StiffnessModel, samples: np.ndarray) -> None:
    along = model.deflection_along(samples, PAYLOAD, GRASP)
    assert along.shape == (50, 6)
    for i in (0, 17, 49):
        d = model.deflection(samples[i], PAYLOAD, GRASP)
        np.testing.assert_allclose(along[i], d.twist, rtol=1e-12, atol=1e-18)


def test_a_configuration_asked_again_gets_the_same_numbers_and_its_own_copy(
    robot: Cabin8, samples: np.ndarray
) -> None:
    """Single configurations are remembered by (q, load case): the same bits, never a shared array.

    Every part of the load case tells cases apart (payload, its centre of mass, frame, wrench, gravity),
    and the remembered answer is the batch's row (the model is evaluated row by row).
    """
    model = StiffnessModel(robot)
    q = samples[5]
    heavier_back = RigidPayload(PAYLOAD.mass, PAYLOAD.com_tool + [0.0, 0.0, 0.05], PAYLOAD.inertia_tool)
    push = np.array([0.0, 0.0, 80.0, 0.0, 0.0, 0.0])
    cases = [
        LoadCase(),
        LoadCase(PAYLOAD),
        LoadCase(heavier_back),
        LoadCase(PAYLOAD, GRASP),
        LoadCase(PAYLOAD, GRASP, push),
        LoadCase(PAYLOAD, GRASP, push, gravity=False),
    ]
    first = [model.deflections(q, case) for case in cases]
    assert len({f.tobytes() for f in first}) == len(cases)  # no two cases share an answer
    batch = [model.deflections(samples, case)[5] for case in cases]
    for case, f, row in zip(cases, first, batch, strict=True):
        again = model.deflections(q[None], case)
        assert np.array_equal(again, f) and np.array_equal(again[0], row)
        again[:] = 0.0  # the caller's copy
        assert np.array_equal(model.deflections(q, case), f)
    for i in range(200):  # many configurations later the answers are still the model's
        model.deflection(samples[i % 50] + 1e-3 * (i // 50), PAYLOAD)
    assert np.array_equal(model.deflections(q, cases[3]), first[3])


def test_threads_sharing_one_model_get_its_numbers(robot: Cabin8, samples: np.ndarray) -> None:
    """Eight threads ask one model for a hundred configurations each: every answer the configuration's own.

    Fifty configurations against a memory of 64, in random orders: entries are added and dropped while
    other threads read them.
    """
    from concurrent.futures import ThreadPoolExecutor

    model = StiffnessModel(robot)
    want = model.deflections(samples, LoadCase(PAYLOAD, GRASP))  # the batch: no memory involved

    def ask(seed: int) -> bool:
        order = np.random.default_rng(seed).integers(0, len(samples), 100)
        return all(np.array_equal(model.deflection(samples[k], PAYLOAD, GRASP).twist, want[k]) for k in order)

    with ThreadPoolExecutor(8) as pool:
        assert all(pool.map(ask, range(8)))


# --------------------------------------------------------------------------------------- compensation
def _goal(robot: Cabin8) -> tuple[np.ndarray, np.ndarray]:
    q = robot.joints_from_drives(robot.home_drives)
    q[4] = 1.2  # arm turned along the cabin axis, as heavy payloads are carried
    return robot.fk(q) @ GRASP, q


def test_compensation_lands_on_the_request(robot: Cabin8, model: StiffnessModel) -> None:
    T_req, q0 = _goal(robot)
    comp = compensate_goal(model, T_req, q0, PAYLOAD, GRASP)
    # Forward deflection of the compensated command, recomputed from its configuration alone.
    T_cmd = robot.fk(comp.q_commanded) @ GRASP
    np.testing.assert_allclose(T_cmd, comp.T_base_frame_commanded, atol=1e-9)
    x = model.deflection(comp.q_commanded, PAYLOAD, GRASP).twist
    e = pose_error(T_req, deflected_pose(T_cmd, x))
    assert np.linalg.norm(e[:3]) < 1e-5 and np.linalg.norm(e[3:]) < 1e-5
    # It did compensate something real, on the same redundant coordinates.
    uncompensated = model.deflection(q0, PAYLOAD, GRASP).translation_m
    assert np.linalg.norm(uncompensated) > 1e-4
    assert comp.q_commanded[3] == q0[3] and comp.q_commanded[6] == q0[6]
    assert len(comp.iterations) <= 6 and comp.iterations[0].residual_m > 1e-4
    # The FE route's deflection of the same command also lands near the request (gravity lumping only).
    x_fe = fe_deflection(robot, comp.q_commanded, PAYLOAD, GRASP)
    e_fe = pose_error(T_req, deflected_pose(T_cmd, x_fe))
    assert np.linalg.norm(e_fe[:3]) < 0.02 * np.linalg.norm(uncompensated)
    doc = comp.to_dict()
    assert set(doc) >= {"nominal", "compensated", "iterations"}


def test_compensation_that_cannot_converge_is_refused(robot: Cabin8, model: StiffnessModel) -> None:
    T_req, q0 = _goal(robot)
    with pytest.raises(DeflectionNotCompensated) as err:
        compensate_goal(model, T_req, q0, PAYLOAD, GRASP, tol_m=1e-15, tol_rad=1e-15, max_iterations=1)
    assert err.value.reason == "compensation_failed"
    assert len(err.value.details["iterations"]) == 2


def test_candidates_compensated_together_get_each_ones_own_outcome_to_the_bit(
    robot: Cabin8, model: StiffnessModel
) -> None:
    """compensate_many: batched iterations, each candidate's steps and result exactly its own alone."""
    from planner.dynamics.compensation import Compensation, compensate_many

    T_req, q0 = _goal(robot)
    gammas, d5s = np.array([q0[3], q0[3] + 0.05, q0[3] - 0.08]), np.array([q0[6], q0[6] - 0.03, q0[6] + 0.02])
    family = redundant_family(robot.desc.serial_chain, T_req @ np.linalg.inv(GRASP), gammas, d5s)
    candidates = [q for q in family if np.all(np.isfinite(q))]
    assert len(candidates) >= 2
    load = LoadCase(PAYLOAD, GRASP)
    for kwargs in ({}, {"tol_m": 1e-15, "tol_rad": 1e-15, "max_iterations": 1}):
        together = compensate_many(model, T_req, candidates, load, **kwargs)
        alone = [compensate_many(model, T_req, [q], load, **kwargs)[0] for q in candidates]
        assert len(together) == len(candidates)
        for a, b in zip(together, alone, strict=True):
            assert type(a) is type(b)
            if isinstance(a, Compensation):
                assert isinstance(b, Compensation)
                assert np.array_equal(a.q_commanded, b.q_commanded)
                assert np.array_equal(a.T_base_frame_commanded, b.T_base_frame_commanded)
                assert a.iterations == b.iterations
                assert np.array_equal(a.deflection.twist, b.deflection.twist)
            else:
                assert isinstance(a, DeflectionNotCompensated) and isinstance(b, DeflectionNotCompensated)
                assert a.message == b.message and a.details == b.details
    converged = compensate_many(model, T_req, candidates, load)
    assert all(isinstance(c, Compensation) for c in converged)  # the default tolerances: every one lands


def test_compensated_configuration_is_the_closed_form_family(robot: Cabin8, model: StiffnessModel) -> None:
    T_req, q0 = _goal(robot)
    comp = compensate_goal(model, T_req, q0, PAYLOAD, GRASP)
    T_tool = comp.T_base_frame_commanded @ np.linalg.inv(GRASP)
    fam = redundant_family(robot.desc.serial_chain, T_tool, np.array([q0[3]]), np.array([q0[6]]))[0]
    np.testing.assert_allclose(fam, comp.q_commanded, atol=1e-12)


# ------------------------------------------------------------------------------------------ description
def _write(tmp_path: Path, mutate) -> Path:  # type: ignore[no-untyped-def]
    raw = yaml.safe_load(default_description_path().read_text())
    mutate(raw)
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


@pytest.mark.parametrize(
    ("mutate", "field"),
    [
        (lambda r: r["stiffness"]["drives"].pop("d5"), "stiffness"),
        (lambda r: r["stiffness"]["drives"].update(d5=-1.0), "stiffness"),
        (lambda r: r["stiffness"]["sections"].update(arm=[0.05, 0.10]), "stiffness.sections.arm"),
        (lambda r: r["stiffness"].update(E_Pa=0), "stiffness.E_Pa"),
    ],
)
def test_invalid_stiffness_data_names_the_field(tmp_path: Path, mutate, field: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(InvalidRobotDescription) as err:
        Cabin8(_write(tmp_path, mutate))
    assert str(err.value.details["field"]).startswith(field)


def test_model_needs_stiffness_data(tmp_path: Path) -> None:
    robot = Cabin8(_write(tmp_path, lambda r: r.pop("stiffness")))
    with pytest.raises(InvalidRobotDescription):
        StiffnessModel(robot)
