"""The paper's facts as data: each sweep file's ``report:`` node (row names, table scale, orderings)."""

from __future__ import annotations

import pytest
from omegaconf import OmegaConf

from tests.test_train import compose_train
from wdss.paths import PROJECT_ROOT, SWEEPS_DIR
from wdss.report.facts import paper_facts, paper_labels, read_facts, sweep_files

# What the report hard-coded before the sweep files stated it: the sweep files must say the same.
LABELS = {
    "none": "No wavelet",
    "dwt_haar": "DWT-haar",
    "swt_haar": "SWT-haar",
    "swt_sym4": "SWT-sym4",
    "swt_db4": "SWT-db4",
    "fusion_ll": "Fusion-LL (SWT-haar)",
    "multi_inr": "Multi-INR (DWT-haar)",
    "fixed2x": "Single-scale (DWT-haar)",
    "bicubic": "Bicubic",
    "bilinear": "Bilinear",
    "bilinear_demodulated": "Bilinear (demod.)",
    "joint_bilateral": "Joint bilateral",
    "joint_bilateral_color": "Joint bilateral (colour)",
    "learned_bilateral": "Learned bilateral",
    "real_esrgan": "Real-ESRGAN",
    "real_esrgan_demodulated": "Real-ESRGAN (demod.)",
    "nsrr": "NSRR",
    "fusesr": "FuseSR",
    "dfasr": "DFASR",
}
SCALES = {
    "ablation_wavelet": "2x",
    "ablation_wavelet_loss": "2x",
    "ablation_arch": "2x",
    "methods": "3x",
    "scales": "avg",
}
ORDERINGS = {
    "ablation_wavelet": (
        ("none", "<", "dwt_haar"),
        ("dwt_haar", "<", "swt_haar"),
        ("swt_haar", "<", "swt_sym4"),
        ("swt_sym4", "<=", "swt_db4"),
    ),
    "methods": (("bicubic", "<", "real_esrgan"), ("real_esrgan", "<", "dfasr"), ("dfasr", "<", "swt_db4")),
}


def test_the_sweep_files_state_the_papers_labels_scales_and_orderings():
    assert paper_labels() == LABELS
    for sweep in sweep_files():
        facts = paper_facts(sweep)
        assert facts.labels == LABELS, sweep
        assert facts.scale == SCALES.get(sweep), sweep
        assert facts.orderings == ORDERINGS.get(sweep, ()), sweep


def test_a_sweep_names_every_row_it_sweeps_as_every_other_sweep_does():
    for sweep, path in sweep_files().items():
        own = read_facts(path)
        variants = str(OmegaConf.load(path).hydra.sweeper.params.get("variant", "")).split(",")
        assert {v.strip() for v in variants if v.strip()} <= set(own.labels), sweep
        assert {key: LABELS[key] for key in own.labels} == own.labels, sweep  # one name per variant everywhere
        assert {v for low, _, high in own.orderings for v in (low, high)} <= set(variants), sweep


def test_runs_of_no_known_sweep_get_the_labels_and_no_table_facts():
    for sweep in (None, "anything", "../../escaped", "../conf/train"):
        facts = paper_facts(sweep)
        assert facts.labels == LABELS and facts.scale is None and facts.orderings == ()


def test_the_report_node_composes_into_every_sweeps_config(tmp_path, monkeypatch):
    monkeypatch.chdir(PROJECT_ROOT)  # sweeps/ find conf/ relative to the project root
    for sweep, path in sweep_files().items():
        cfg = compose_train([], tmp_path, config_dir=SWEEPS_DIR, name=sweep)
        assert OmegaConf.to_container(cfg.report) == OmegaConf.to_container(OmegaConf.load(path).report), sweep


@pytest.mark.parametrize(
    ("node", "message"),
    [
        ("report: {label: {none: x}}", r"sweep\.yaml: report takes the keys labels, scale, orderings"),
        ("report: {scale: 3}", r"sweep\.yaml: report\.scale is a test scale such as 2x, or avg; got 3"),
        ("report: {orderings: [none > dwt_haar]}", r"sweep\.yaml: report\.orderings\[0\] is 'none > dwt_haar'"),
        ("report: {orderings: none < dwt_haar}", r"sweep\.yaml: report\.orderings is a list of claims"),
        ("report: {labels: [none]}", r"sweep\.yaml: report\.labels maps a variant to its row name"),
    ],
)
def test_a_malformed_report_node_is_refused_naming_the_file_and_key(node, message, tmp_path):
    path = tmp_path / "sweep.yaml"
    path.write_text(node + "\n")
    with pytest.raises(SystemExit, match=message):
        read_facts(path)
