# Rules of the loop stage (wiring only: every rule calls capsule-cli).
# Per kind: synth with a hidden effect -> compare the base model -> diagnose --write-model ->
# compare the improved model -> ledger plot, under results/loop/<kind>/ (each demo its own ledgers).
# Plus the published-data loops (configs/data/) under results/loop/published_<name>/: like with like (one
# statistic per table), and an effect is added only when the verdict names one (else the model is unchanged).
# Appends its final outputs to LOOP_TARGETS when config["loop"]["enabled"].

LOOP = STUDY.loop
LOOP_DIR = f"{RESULTS}/loop"
LOOP_PKG = pkg("effects/registry.py", "effects/model.py", "effects/friction.py", "effects/pressure.py",
               "effects/relaxation.py", "steps/compare.py", "steps/diagnose.py", "steps/crossval.py",
               "steps/residual_tests.py", "models/friction.py", "models/contact.py", "models/viscoelastic.py")

LOOP_DEMOS = {
    # kind: (true model with the hidden effect, base model, design, noise SD in the response unit)
    "friction": ("friction_coulomb_eq17_truth.yaml", "coulomb.yaml", "friction_speed.csv", LOOP.noise_sd_friction_mN),
    "pressure": ("pressure_hoop_curved_truth.yaml", "pressure_hoop.yaml", "pressure_curved.csv",
                 LOOP.noise_sd_pressure_kPa),
    "relaxation": ("relaxation_two_arm_truth.yaml", "relaxation_maxwell.yaml", "relaxation_record.csv",
                   LOOP.noise_sd_relaxation_kPa),
}
LOOP_PUBLISHED = {
    # name: (base model, measurement table)
    "case1_friction": ("coulomb.yaml", "seed000_case1_friction.csv"),
    # like with like: the FE maxima only (the averages, 8-9 kPa, are a different statistic; two rows)
    "curved_intestine": ("pressure_hoop_fixed.yaml", "seed001_curved_intestine_FE_max.csv"),
}


def _demo(kind, i):
    return str(CONFIGS / ("models" if i < 2 else "designs") / LOOP_DEMOS[kind][i])


rule loop_synth:
    input:
        truth=lambda w: _demo(w.kind, 0),
        design=lambda w: _demo(w.kind, 2),
        code=LOOP_PKG,
    output:
        data=f"{LOOP_DIR}/{{kind}}/{{kind}}_synthetic.csv",
    params:
        noise=lambda w: LOOP_DEMOS[w.kind][3],
        reps=LOOP.replicates,
        seed=STUDY.seed,
    log:
        f"{LOOP_DIR}/{{kind}}/logs/synth.log",
    wildcard_constraints:
        kind="friction|pressure|relaxation",
    shell:
        "capsule-cli synth --model {input.truth} --design {input.design} --noise-sd {params.noise} "
        "--replicates {params.reps} --seed {params.seed} --out {output.data} --quiet 2> {log}"


def _loop_data(w):
    if w.demo in LOOP_DEMOS:
        return f"{LOOP_DIR}/{w.demo}/{w.demo}_synthetic.csv"
    return str(CONFIGS / "data" / LOOP_PUBLISHED[w.demo.removeprefix("published_")][1])


def _loop_base(w):
    if w.demo in LOOP_DEMOS:
        return _demo(w.demo, 1)
    return str(CONFIGS / "models" / LOOP_PUBLISHED[w.demo.removeprefix("published_")][0])


rule loop_compare_base:
    input:
        model=_loop_base,
        data=_loop_data,
        code=LOOP_PKG,
    output:
        metrics=f"{LOOP_DIR}/{{demo}}/compare_base/metrics.json",
        fit=captioned(f"{LOOP_DIR}/{{demo}}/compare_base/fit.png", "loop_fit", CAT_LOOP, "Model against data"),
        ledger=f"{LOOP_DIR}/{{demo}}/ledger_0_base.parquet",
    params:
        out=f"{LOOP_DIR}/{{demo}}/compare_base",
        folds=LOOP.folds,
    log:
        f"{LOOP_DIR}/{{demo}}/logs/compare_base.log",
    shell:
        "capsule-cli compare --model {input.model} --data {input.data} --out {params.out} "
        "--ledger {output.ledger} --folds {params.folds} --quiet 2> {log}"


rule loop_diagnose:
    input:
        model=_loop_base,
        data=_loop_data,
        code=LOOP_PKG,
    output:
        diagnosis=f"{LOOP_DIR}/{{demo}}/diagnose/diagnosis.json",
        report=captioned(f"{LOOP_DIR}/{{demo}}/diagnose/diagnosis.md", "loop_diagnosis", CAT_LOOP, "Diagnoses"),
        model=f"{LOOP_DIR}/{{demo}}/improved_model.yaml",
    params:
        out=f"{LOOP_DIR}/{{demo}}/diagnose",
        folds=LOOP.folds,
    log:
        f"{LOOP_DIR}/{{demo}}/logs/diagnose.log",
    shell:
        "capsule-cli diagnose --model {input.model} --data {input.data} --out {params.out} "
        "--write-model {output.model} --folds {params.folds} --quiet 2> {log}"


rule loop_compare_improved:
    input:
        model=f"{LOOP_DIR}/{{demo}}/improved_model.yaml",
        data=_loop_data,
        code=LOOP_PKG,
    output:
        metrics=f"{LOOP_DIR}/{{demo}}/compare_improved/metrics.json",
        fit=captioned(f"{LOOP_DIR}/{{demo}}/compare_improved/fit.png", "loop_fit", CAT_LOOP, "Model against data"),
        ledger=f"{LOOP_DIR}/{{demo}}/ledger_1_improved.parquet",
    params:
        out=f"{LOOP_DIR}/{{demo}}/compare_improved",
        folds=LOOP.folds,
    log:
        f"{LOOP_DIR}/{{demo}}/logs/compare_improved.log",
    shell:
        "capsule-cli compare --model {input.model} --data {input.data} --out {params.out} "
        "--ledger {output.ledger} --folds {params.folds} --quiet 2> {log}"


rule loop_ledger_plot:
    input:
        base=f"{LOOP_DIR}/{{demo}}/ledger_0_base.parquet",
        improved=f"{LOOP_DIR}/{{demo}}/ledger_1_improved.parquet",
    output:
        fig=captioned(f"{LOOP_DIR}/{{demo}}/ledger.png", "loop_ledger", CAT_LOOP, "Error falling (ledgers)"),
    log:
        f"{LOOP_DIR}/{{demo}}/logs/ledger_plot.log",
    shell:
        "capsule-cli ledger plot --ledger {input.base} --ledger {input.improved} --out {output.fig} 2> {log}"


if LOOP.enabled:
    _demos = list(LOOP.kinds) + ([f"published_{k}" for k in LOOP_PUBLISHED] if LOOP.published else [])
    LOOP_TARGETS += [f"{LOOP_DIR}/{d}/ledger.png" for d in _demos]
    LOOP_TARGETS += [f"{LOOP_DIR}/{d}/diagnose/diagnosis.md" for d in _demos]


# ---------------------------------------------------------------------------
# loop_dynamics: the dynamics loop demo (issue 12) under results/loop/dyn_<kind>/:
# synth with a hidden effect -> compare the base model -> diagnose --write-model ->
# compare the improved model -> ledger plot. The protocol is in the model files. File names differ from the
# quasi-static demos' so that no output pattern of theirs matches (their {demo} wildcard spans folders).

LOOP_DYN_PKG = LOOP_PKG + pkg("effects/dynamics.py", "dynamics/system.py", "dynamics/engine.py",
                              "dynamics/model.py") + pkg_dir("steps/dynamics_loop")
LOOP_DYN_DEMOS = {
    # (kind, the kind's demo in loop:): (true model with the hidden effect, base model)
    ("progression", "sdf"): ("progression_sdf_truth.yaml", "progression_base.yaml"),
    ("progression", "secondary"): ("progression_secondary_truth.yaml", "progression_base_short.yaml"),
    ("trajectory", "tilt"): ("trajectory_tilt_truth.yaml", "trajectory_base.yaml"),
}
LOOP_DYN_CANDIDATES = "".join(f" --candidate {c}" for c in LOOP.dynamics_candidates)
# per kind: its demo (a key of LOOP_DYN_DEMOS) and synth's design, noise SD (mm/s; mm), replicates and extra flags
LOOP_DYN_SYNTH = {
    "progression": dict(demo=LOOP.dynamics_demo, design=LOOP.dynamics_design, noise=LOOP.noise_sd_progression_mm_s,
                        reps=LOOP.dynamics_replicates, extra=""),
    "trajectory": dict(demo=LOOP.trajectory_demo, design=LOOP.trajectory_design, noise=LOOP.noise_sd_trajectory_mm,
                       reps=1, extra=f" --frame-rate-Hz {LOOP.frame_rate_Hz:g}"),
}


def _dyn_model(w, i):
    return str(CONFIGS / "models" / LOOP_DYN_DEMOS[(w.dkind, LOOP_DYN_SYNTH[w.dkind]["demo"])][i])


rule loop_dynamics_synth:
    input:
        truth=lambda w: _dyn_model(w, 0),
        design=lambda w: str(CONFIGS / "designs" / LOOP_DYN_SYNTH[w.dkind]["design"]),
        code=LOOP_DYN_PKG,
    output:
        data=f"{LOOP_DIR}/dyn_{{dkind}}/{{dkind}}_synthetic.csv",
    params:
        noise=lambda w: LOOP_DYN_SYNTH[w.dkind]["noise"],
        reps=lambda w: LOOP_DYN_SYNTH[w.dkind]["reps"],
        extra=lambda w: LOOP_DYN_SYNTH[w.dkind]["extra"],
        seed=STUDY.seed,
    log:
        f"{LOOP_DIR}/dyn_{{dkind}}/logs/synth.log",
    shell:
        "capsule-cli synth --model {input.truth} --design {input.design} --noise-sd {params.noise} "
        "--replicates {params.reps}{params.extra} --seed {params.seed} --out {output.data} --quiet 2> {log}"


rule loop_dynamics_compare_base:
    input:
        model=lambda w: _dyn_model(w, 1),
        data=f"{LOOP_DIR}/dyn_{{dkind}}/{{dkind}}_synthetic.csv",
        code=LOOP_DYN_PKG,
    output:
        metrics=f"{LOOP_DIR}/dyn_{{dkind}}/compare_as_is/metrics.json",
        fig=captioned(f"{LOOP_DIR}/dyn_{{dkind}}/compare_as_is/residuals.png", "loop_dyn_residuals", CAT_LOOP,
                      "Dynamics: residuals"),
        ledger=f"{LOOP_DIR}/dyn_{{dkind}}/ledger_as_is.parquet",
    params:
        out=f"{LOOP_DIR}/dyn_{{dkind}}/compare_as_is",
        folds=LOOP.folds,
        effort=LOOP.dynamics_effort,
    log:
        f"{LOOP_DIR}/dyn_{{dkind}}/logs/compare_as_is.log",
    shell:
        "capsule-cli compare --model {input.model} --data {input.data} --out {params.out} "
        "--ledger {output.ledger} --folds {params.folds} --effort {params.effort} --quiet 2> {log}"


rule loop_dynamics_diagnose:
    input:
        model=lambda w: _dyn_model(w, 1),
        data=f"{LOOP_DIR}/dyn_{{dkind}}/{{dkind}}_synthetic.csv",
        code=LOOP_DYN_PKG,
    output:
        diagnosis=f"{LOOP_DIR}/dyn_{{dkind}}/diagnosis/diagnosis.json",
        report=f"{LOOP_DIR}/dyn_{{dkind}}/diagnosis/diagnosis.md",
        model=f"{LOOP_DIR}/dyn_{{dkind}}/model_with_effect.yaml",
    params:
        out=f"{LOOP_DIR}/dyn_{{dkind}}/diagnosis",
        folds=LOOP.folds,
        effort=LOOP.dynamics_effort,
    log:
        f"{LOOP_DIR}/dyn_{{dkind}}/logs/diagnose.log",
    shell:
        "capsule-cli diagnose --model {input.model} --data {input.data} --out {params.out} "
        "--write-model {output.model} --folds {params.folds} --effort {params.effort}"
        + LOOP_DYN_CANDIDATES + " --quiet 2> {log}"


rule loop_dynamics_compare_improved:
    input:
        model=f"{LOOP_DIR}/dyn_{{dkind}}/model_with_effect.yaml",
        data=f"{LOOP_DIR}/dyn_{{dkind}}/{{dkind}}_synthetic.csv",
        code=LOOP_DYN_PKG,
    output:
        metrics=f"{LOOP_DIR}/dyn_{{dkind}}/compare_with_effect/metrics.json",
        fig=captioned(f"{LOOP_DIR}/dyn_{{dkind}}/compare_with_effect/residuals.png", "loop_dyn_residuals", CAT_LOOP,
                      "Dynamics: residuals"),
        ledger=f"{LOOP_DIR}/dyn_{{dkind}}/ledger_with_effect.parquet",
    params:
        out=f"{LOOP_DIR}/dyn_{{dkind}}/compare_with_effect",
        folds=LOOP.folds,
        effort=LOOP.dynamics_effort,
    log:
        f"{LOOP_DIR}/dyn_{{dkind}}/logs/compare_with_effect.log",
    shell:
        "capsule-cli compare --model {input.model} --data {input.data} --out {params.out} "
        "--ledger {output.ledger} --folds {params.folds} --effort {params.effort} --quiet 2> {log}"


rule loop_dynamics_ledger_plot:
    input:
        base=f"{LOOP_DIR}/dyn_{{dkind}}/ledger_as_is.parquet",
        improved=f"{LOOP_DIR}/dyn_{{dkind}}/ledger_with_effect.parquet",
    output:
        fig=captioned(f"{LOOP_DIR}/dyn_{{dkind}}/error_ledger.png", "loop_dyn_ledger", CAT_LOOP,
                      "Error falling (ledgers)"),
    log:
        f"{LOOP_DIR}/dyn_{{dkind}}/logs/ledger_plot.log",
    shell:
        "capsule-cli ledger plot --ledger {input.base} --ledger {input.improved} --out {output.fig} 2> {log}"


if LOOP.enabled:
    LOOP_TARGETS += [f"{LOOP_DIR}/dyn_{k}/error_ledger.png" for k in LOOP.dynamics_kinds]
    LOOP_TARGETS += [f"{LOOP_DIR}/dyn_{k}/diagnosis/diagnosis.md" for k in LOOP.dynamics_kinds]
