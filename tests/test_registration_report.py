"""The Qt-free registration outputs: pair rows, mapped preop nodes, pairing CSV and the PNG report."""

import csv
import dataclasses
import struct

import numpy as np
import pytest

from snreg import __version__, geometry
from snreg.nodes import NodeSet, read_nodes, write_nodes
from snreg.registration import CONFIDENT, RegistrationResult, register
from snreg.registration.report import (FAR_NODE_MM, NO_HOT_SPOT, REPORT_DPI, REPORT_SIZE_IN, VIEWS, mapped_preop,
                                       node_warnings, pair_rows, registration_figure, save_report_png, write_pairs_csv)
from snreg.registration.report_meta import REPORT_KEY, ReportContext, read_report_metadata, sidecar_path


@pytest.fixture
def case(pelvic_nodes):
    """Six pelvic nodes, moved by 20 deg and 30 mm with 1 mm noise, shuffled, plus one extra intraop node far away."""
    xyz, labels = pelvic_nodes
    rng = np.random.default_rng(3)
    truth = geometry.transform_from_euler(20.0, 5.0, -5.0, [30.0, -10.0, 5.0])
    order = rng.permutation(len(xyz))
    intraop_xyz = np.vstack([geometry.apply(truth, xyz)[order] + rng.normal(0, 1.0, (6, 3)), [[200.0, 200.0, 200.0]]])
    preop = NodeSet.from_xyz(xyz, labels, prefix="P")
    intraop = NodeSet.from_xyz(intraop_xyz, [labels[k] for k in order] + ["PR L"], prefix="I")
    result = register(preop.xyz, intraop.xyz, method="global")
    return preop, intraop, result, np.append(order, -1), truth


def test_pair_rows_follow_the_pairing_with_none_for_a_node_from_no_hot_spot(case):
    preop, intraop, result, truth_pairing, _ = case
    assert np.array_equal(result.pairing, truth_pairing)
    rows = pair_rows(preop, intraop, result)
    assert [r.intraop_id for r in rows] == intraop.ids
    assert [r.preop_id for r in rows] == [preop.ids[n] for n in truth_pairing[:-1]] + [NO_HOT_SPOT]
    assert all(r.shared_with == () for r in rows)
    assert [r.preop_label for r in rows[:-1]] == [r.intraop_label for r in rows[:-1]]
    assert np.allclose([r.distance_mm for r in rows], result.distances_mm)
    assert [r.confident for r in rows] == list(result.confidence >= CONFIDENT)


def test_pair_rows_refuse_node_sets_the_result_was_not_made_from(case):
    preop, intraop, result, _, _ = case
    with pytest.raises(ValueError, match="node sets the registration was run on"):
        pair_rows(preop, NodeSet.from_xyz(intraop.xyz[:4]), result)
    with pytest.raises(ValueError, match="node sets the registration was run on"):
        pair_rows(NodeSet.from_xyz(preop.xyz[:2]), intraop, result)


def test_mapped_preop_lands_on_the_true_positions_and_round_trips_through_slicer(case, tmp_path):
    preop, _, result, _, truth = case
    mapped = mapped_preop(preop, result)
    assert mapped.ids == preop.ids and mapped.labels == preop.labels and mapped.frame == "trocar"
    assert np.max(np.linalg.norm(mapped.xyz - geometry.apply(truth, preop.xyz), axis=1)) < 3.0
    write_nodes(mapped, tmp_path / "mapped.mrk.json")
    back = read_nodes(tmp_path / "mapped.mrk.json")
    assert back.ids == preop.ids and back.labels == preop.labels
    assert np.allclose(back.xyz, mapped.xyz)


def test_pairs_csv_reads_back_with_comments_skipped(case, tmp_path):
    preop, intraop, result, truth_pairing, _ = case
    path = write_pairs_csv(tmp_path / "pairs.csv", preop, intraop, result)
    lines = path.read_text(encoding="utf-8").splitlines()
    assert lines[0] == "# method: global" and lines[1].startswith("# rms_mm: ")
    table = list(csv.DictReader(line for line in lines if not line.startswith("#")))
    assert [row["intraop_id"] for row in table] == intraop.ids
    assert [row["hot_spot"] for row in table] == [preop.ids[n] for n in truth_pairing[:-1]] + [""]
    assert [row["shared_with"] for row in table] == [""] * len(intraop.ids)
    assert np.allclose([float(row["distance_mm"]) for row in table], result.distances_mm, atol=1e-3)
    transform = np.array(lines[2].split(":", 1)[1].split(), dtype=float).reshape(4, 4)
    assert np.allclose(transform, result.transform, atol=1e-4)


def test_figure_draws_both_sets_in_three_views_with_the_pairs(case):
    preop, intraop, result, _, _ = case
    figure = registration_figure(preop, intraop, result)
    views, table = figure.axes[:3], figure.axes[3]
    moved = geometry.apply(result.transform, preop.xyz)
    for ax, (name, h, v) in zip(views, VIEWS):
        assert ax.get_title().startswith(name) and "trocar frame" in ax.get_title()
        assert ax.get_xlabel() == f"{'xyz'[h]} trocar (mm)" and ax.get_ylabel() == f"{'xyz'[v]} trocar (mm)"
        preop_dots, intraop_dots = ax.collections[:2]
        assert np.allclose(preop_dots.get_offsets(), moved[:, [h, v]])
        assert np.allclose(intraop_dots.get_offsets(), intraop.xyz[:, [h, v]])
        assert len(ax.lines) == int(np.sum(result.pairing >= 0))
    assert any(f"RMS {result.rms_mm:.2f} mm" in text.get_text() for text in figure.texts)
    assert not {"axial", "coronal", "sagittal"} & {w for ax in views for w in ax.get_title().split()}
    assert "global" in table.get_title()
    cell_texts = {cell.get_text().get_text() for cell in table.tables[0].get_celld().values()}
    assert NO_HOT_SPOT in cell_texts and set(intraop.ids) <= cell_texts


def test_figure_shades_rows_below_the_confidence_threshold(case):
    preop, intraop, result, _, _ = case
    doubtful = RegistrationResult(result.method, result.transform, result.pairing, result.distances_mm,
                                  result.rms_mm, np.where(np.arange(len(intraop)) == 1, 0.4, 1.0), result.pairing_rule)
    cells = registration_figure(preop, intraop, doubtful).axes[3].tables[0].get_celld()
    shaded = {row for (row, _), cell in cells.items() if row > 0 and cell.get_facecolor()[:3] != (1.0, 1.0, 1.0)}
    assert shaded == {2}                     # table row 0 is the header; intraop node 1 is row 2


CONTEXT = ReportContext(case_id="phantom-01", session_path="/data/cases/phantom-01.h5", stereo_rms_px=0.31,
                        stereo_views=30, stereo_created_utc="2024-05-01T10:00:00+00:00", stereo_version="ab12cd34",
                        trocar_camera_mm=158.0, chain_version="99ee1122", date_utc="2024-05-02T08:30:00+00:00")


def _png_size(path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", data[16:24])


@pytest.mark.slow
def test_png_report_is_the_documented_width_and_as_tall_as_its_content(case, tmp_path):
    preop, intraop, result, _, _ = case
    path = save_report_png(tmp_path / "report.png", preop, intraop, result)
    width, height = _png_size(path)
    assert width == round(REPORT_SIZE_IN[0] * REPORT_DPI) and 600 < height < 1000
    from PIL import Image
    grey = np.asarray(Image.open(path).convert("L"), dtype=float)
    ink_rows = np.flatnonzero((grey < 200).any(axis=1))
    assert height - ink_rows[-1] < 0.05 * height             # no blank band at the bottom (it was a third)
    more = NodeSet.from_xyz(np.vstack([intraop.xyz, intraop.xyz + 300.0]), prefix="I")
    longer = register(preop.xyz, more.xyz, method="icp")
    assert _png_size(save_report_png(tmp_path / "long.png", preop, more, longer))[1] > height


def test_report_metadata_reads_back_from_the_png_text_chunk_and_the_sidecar_json(case, tmp_path):
    preop, intraop, result, _, _ = case
    path = save_report_png(tmp_path / "phantom-01_global_report.png", preop, intraop, result, context=CONTEXT)
    meta = read_report_metadata(path)
    assert read_report_metadata(sidecar_path(path)) == meta
    assert sidecar_path(path) == tmp_path / "phantom-01_global_report.json"
    assert meta["case_id"] == "phantom-01" and meta["session_file"] == "phantom-01.h5"
    assert meta["date_utc"] == "2024-05-02T08:30:00+00:00" and meta["snreg_version"] == __version__
    assert meta["method"] == "global" and meta["rms_mm"] == pytest.approx(result.rms_mm, abs=1e-4)
    assert (meta["n_intraop"], meta["n_paired"], meta["n_extra"]) == (7, 6, 1) and meta["missing_preop_ids"] == []
    assert meta["stereo_rms_px"] == 0.31 and meta["stereo_views"] == 30 and meta["chain_version"] == "99ee1122"
    assert "stereo RMS 0.31 px, 30 views" in meta["calibration"] and "158.0 mm" in meta["calibration"]
    assert np.allclose(meta["intraop_from_preop"], result.transform, atol=1e-5)
    from PIL import Image
    with Image.open(path) as image:
        text = image.info
    assert text["Software"] == f"snreg {__version__}" and "case phantom-01" in text["Description"]
    assert REPORT_KEY in text
    figure_text = " ".join(t.get_text() for t in registration_figure(preop, intraop, result, meta=meta).texts)
    for fact in ("case phantom-01", "2024-05-02T08:30:00+00:00", "phantom-01.h5", "stereo RMS 0.31 px", __version__,
                 "RMS", "6 of 7 intraop nodes paired"):
        assert fact in figure_text


def test_a_png_without_report_metadata_is_refused(tmp_path):
    from PIL import Image
    Image.new("RGB", (4, 4)).save(tmp_path / "other.png")
    with pytest.raises(ValueError, match="not an snreg report"):
        read_report_metadata(tmp_path / "other.png")


def test_node_warnings_name_far_pairs_and_extra_nodes(case):
    preop, intraop, result, _, _ = case
    rows = pair_rows(preop, intraop, result)
    warnings = node_warnings(rows)
    assert len(warnings) == 1 and warnings[0].startswith(f"{intraop.ids[-1]} came from no imaged hot spot")
    far = dataclasses.replace(rows[0], distance_mm=372.0)             # a paired node 372 mm away
    near = dataclasses.replace(rows[1], distance_mm=FAR_NODE_MM)      # at the limit: no warning
    warnings = node_warnings([far, near])
    assert warnings == [f"{far.intraop_id} is 372 mm from its hot spot {far.preop_id} (more than 20 mm): check this "
                        "pairing and the stored node"]
    assert node_warnings([far], far_mm=400.0) == []
