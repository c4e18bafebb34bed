# Rules of the friction stage (wiring only: every rule calls capsule-cli).
# Appends its final outputs to FRICTION_TARGETS when config["friction"]["enabled"].
# Tables: hoop-friction components over speed x R_i (seed 000 eqs 3-16), model curves (Coulomb eq 1,
# eqs 17-18), synthetic Case 1 pull tests (eq 17 + noise, via `capsule-cli synth`) and their fits.
# Figures (seed 000 Figs 9c, 13c and the R_i sensitivity) read those tables.

C_FRICTION = STUDY.friction
FRICTION_DIR = f"{RESULTS}/friction"
FRICTION_REFERENCE = str(CONFIGS / "reference" / "friction_seed000.csv")
FRICTION_PKG = pkg("models/friction.py", "models/contact.py", "steps/friction.py", "cli/friction.py")
FRICTION_PLOT_PKG = pkg("plots/friction.py", "plots/style.py", "cli/friction.py")
FRICTION_CURVE_MODELS = {
    "coulomb": str(CONFIGS / "models" / "coulomb.yaml"),
    "seed000_eq17": str(CONFIGS / "models" / "friction_seed000_eq17.yaml"),
    "seed000_eq18": str(CONFIGS / "models" / "friction_seed000_eq18.yaml"),
}
FRICTION_FIT_FILES = ("fit.json", "band.parquet", "residuals.parquet", "fit.png")


rule friction_hoop_grid:
    input:
        params=str(CONFIGS / "params" / "capsule_intestine.yaml"),
        code=FRICTION_PKG,
    output:
        table=f"{FRICTION_DIR}/hoop_components.parquet",
    params:
        radii=C_FRICTION.hoop_Ri_mm,
        speeds=C_FRICTION.hoop_speeds_mm_s,
        wall=C_FRICTION.wall_mode,
    log:
        f"{FRICTION_DIR}/logs/friction_hoop_grid.log",
    benchmark:
        f"{FRICTION_DIR}/benchmarks/friction_hoop_grid.tsv"
    shell:
        "capsule-cli friction hoop --Ri-mm {params.radii} --speeds-mm-s {params.speeds} "
        "--wall-mode {params.wall} --out {output.table} --quiet > {log} 2>&1"


rule friction_model_curve:
    input:
        model=lambda wc: FRICTION_CURVE_MODELS[wc.model],
        code=FRICTION_PKG + pkg("effects/friction.py", "effects/model.py"),
    output:
        table=f"{FRICTION_DIR}/curve_{{model}}.parquet",
    wildcard_constraints:
        model="|".join(FRICTION_CURVE_MODELS),
    params:
        speeds=C_FRICTION.curve_speeds_mm_s,
    log:
        f"{FRICTION_DIR}/logs/friction_model_curve_{{model}}.log",
    shell:
        "capsule-cli friction predict --model {input.model} --speeds-mm-s {params.speeds} "
        "--out {output.table} --quiet > {log} 2>&1"


rule friction_synth_case1:
    input:
        model=str(REPO / C_FRICTION.synthetic_model),
        design=str(REPO / C_FRICTION.synthetic_design),
        code=pkg("models/friction.py", "effects/friction.py", "steps/synth.py"),
    output:
        table=f"{FRICTION_DIR}/case1_friction_synthetic.parquet",
    params:
        replicates=C_FRICTION.synthetic_replicates,
        noise=C_FRICTION.synthetic_noise_sd_mN,
        seed=STUDY.seed,
    log:
        f"{FRICTION_DIR}/logs/friction_synth_case1.log",
    shell:
        "capsule-cli synth --model {input.model} --design {input.design} --replicates {params.replicates} "
        "--noise-sd {params.noise} --seed {params.seed} --out {output.table} --quiet > {log} 2>&1"


rule friction_fit_case1:
    input:
        data=rules.friction_synth_case1.output.table,
        code=FRICTION_PKG + pkg("fitting.py", "plots/friction.py"),
    output:
        **{f.split(".")[0] + "_" + f.split(".")[1]: f"{FRICTION_DIR}/fit_case1_{{law}}/{f}" for f in FRICTION_FIT_FILES
           if f != "fit.png"},
        fit_png=captioned(f"{FRICTION_DIR}/fit_case1_{{law}}/fit.png", "friction_fit", CAT_FRICTION,
                          "Fits to synthetic Case 1 pull tests (seed 000 eq 17)"),
    wildcard_constraints:
        law="power|power_fixed_n|viscous|stribeck|coulomb",
    params:
        out=lambda wc: f"{FRICTION_DIR}/fit_case1_{wc.law}",
        n_fixed=C_FRICTION.n_fixed,
        n_starts=C_FRICTION.n_starts,
        seed=STUDY.seed,
    log:
        f"{FRICTION_DIR}/logs/friction_fit_case1_{{law}}.log",
    benchmark:
        f"{FRICTION_DIR}/benchmarks/friction_fit_case1_{{law}}.tsv"
    shell:
        "capsule-cli friction fit --data {input.data} --law {wildcards.law} --n-fixed {params.n_fixed} "
        "--groups trial --n-starts {params.n_starts} --seed {params.seed} --out {params.out} --quiet > {log} 2>&1"


rule friction_figure_speed:
    input:
        reference=FRICTION_REFERENCE,
        hoop=rules.friction_hoop_grid.output.table,
        coulomb=f"{FRICTION_DIR}/curve_coulomb.parquet",
        eq17=f"{FRICTION_DIR}/curve_seed000_eq17.parquet",
        eq18=f"{FRICTION_DIR}/curve_seed000_eq18.parquet",
        fit=[f"{FRICTION_DIR}/fit_case1_{C_FRICTION.fit_laws[0]}/{f}" for f in FRICTION_FIT_FILES],
        code=FRICTION_PLOT_PKG,
    output:
        figure=captioned(f"{FRICTION_DIR}/friction_vs_speed.png", "friction_vs_speed", CAT_FRICTION,
                         "Friction over speed, Cases 1 and 4 (seed 000 Figs 9c, 13c)"),
    params:
        fit=f"{FRICTION_DIR}/fit_case1_{C_FRICTION.fit_laws[0]}",
        radii=C_FRICTION.figure_Ri_mm,
    log:
        f"{FRICTION_DIR}/logs/friction_figure_speed.log",
    shell:
        "capsule-cli friction plot-speed --reference {input.reference} --hoop {input.hoop} "
        "--coulomb {input.coulomb} --case1-law {input.eq17} --case4-law {input.eq18} --fit {params.fit} "
        "--Ri-mm {params.radii} --out {output.figure} --quiet > {log} 2>&1"


rule friction_figure_radius:
    input:
        reference=FRICTION_REFERENCE,
        hoop=rules.friction_hoop_grid.output.table,
        code=FRICTION_PLOT_PKG,
    output:
        figure=captioned(f"{FRICTION_DIR}/hoop_friction_vs_radius.png", "friction_hoop_vs_radius", CAT_FRICTION,
                         "Hoop friction over R_i (seed 000 eqs 3-16)"),
    params:
        speed=C_FRICTION.components_speed_mm_s,
    log:
        f"{FRICTION_DIR}/logs/friction_figure_radius.log",
    shell:
        "capsule-cli friction plot-radius --hoop {input.hoop} --reference {input.reference} "
        "--speed-mm-s {params.speed} --out {output.figure} --quiet > {log} 2>&1"


if C_FRICTION.enabled:
    FRICTION_TARGETS += [
        rules.friction_figure_speed.output.figure,
        rules.friction_figure_radius.output.figure,
    ] + [f"{FRICTION_DIR}/fit_case1_{law}/{f}" for law in C_FRICTION.fit_laws for f in FRICTION_FIT_FILES]
