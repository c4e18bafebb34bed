# Rules of the contact stage (wiring only: every rule calls capsule-cli).
# Appends its final outputs to CONTACT_TARGETS when config["contact"]["enabled"].
# Tables: pressures per case over speed, hoop pressure over speed x R_i, over R_i, along the capsule,
# and over the end length; the published values as a Parquet table with citations. Figures read tables.

C_CONTACT = STUDY.contact
CONTACT_DIR = f"{RESULTS}/contact"
CONTACT_PARAMS = str(CONFIGS / "params" / f"{C_CONTACT.params}.yaml")
CONTACT_PKG = pkg("models/contact.py", "steps/contact.py", "cli/contact.py")
CONTACT_PLOT_PKG = pkg("plots/contact.py", "plots/style.py", "cli/contact.py")


def _csv(values):
    return ",".join(f"{v:g}" for v in values)


def _range(r):
    return f"{r[0]:g}:{r[1]:g}:{int(r[2])}"


rule contact_reference:
    input:
        csv=str(CONFIGS / "reference" / "contact_pressure.csv"),
        code=pkg("steps/contact.py", "cli/contact.py"),
    output:
        table=f"{CONTACT_DIR}/reference_pressures.parquet",
    log:
        f"{CONTACT_DIR}/logs/contact_reference.log",
    shell:
        "capsule-cli contact-reference --reference {input.csv} --out {output.table} --quiet > {log} 2>&1"


rule contact_cases_vs_speed:
    input:
        params=CONTACT_PARAMS,
        cases=str(CONFIGS / "params" / "contact_cases.yaml"),
        code=CONTACT_PKG,
    output:
        table=f"{CONTACT_DIR}/cases_vs_speed.parquet",
    params:
        speeds=_range(C_CONTACT.speed_range_mm_s),
        walls=",".join(C_CONTACT.wall_modes),
        case2=C_CONTACT.case2_geometry,
    log:
        f"{CONTACT_DIR}/logs/contact_cases_vs_speed.log",
    benchmark:
        f"{CONTACT_DIR}/benchmarks/contact_cases_vs_speed.tsv"
    shell:
        "capsule-cli contact --model all --speeds {params.speeds} --wall-mode {params.walls} "
        "--case2-geometry {params.case2} --params {input.params} --out {output.table} --quiet > {log} 2>&1"


rule contact_hoop_vs_speed:
    input:
        params=CONTACT_PARAMS,
        code=CONTACT_PKG,
    output:
        table=f"{CONTACT_DIR}/hoop_vs_speed.parquet",
    params:
        speeds=_range(C_CONTACT.speed_range_mm_s),
        radii=_csv(C_CONTACT.hoop_Ri_mm),
        walls=",".join(C_CONTACT.wall_modes),
    log:
        f"{CONTACT_DIR}/logs/contact_hoop_vs_speed.log",
    shell:
        "capsule-cli contact --model hoop --speeds {params.speeds} --Ri-mm {params.radii} "
        "--wall-mode {params.walls} --params {input.params} --out {output.table} --quiet > {log} 2>&1"


rule contact_hoop_vs_radius:
    input:
        params=CONTACT_PARAMS,
        code=CONTACT_PKG,
    output:
        table=f"{CONTACT_DIR}/hoop_vs_radius.parquet",
    params:
        speeds=_csv(C_CONTACT.Ri_sweep_speeds_mm_s),
        radii=_range(C_CONTACT.Ri_range_mm),
        walls=",".join(C_CONTACT.wall_modes),
    log:
        f"{CONTACT_DIR}/logs/contact_hoop_vs_radius.log",
    shell:
        "capsule-cli contact --model hoop --speed-mm-s {params.speeds} --Ri-range {params.radii} "
        "--wall-mode {params.walls} --params {input.params} --out {output.table} --quiet > {log} 2>&1"


rule contact_hoop_profile:
    input:
        params=CONTACT_PARAMS,
        code=CONTACT_PKG,
    output:
        table=f"{CONTACT_DIR}/hoop_profile_summary.parquet",
        profile=f"{CONTACT_DIR}/hoop_profile.parquet",
    params:
        speeds=_csv(C_CONTACT.profile_speeds_mm_s),
        walls=",".join(C_CONTACT.wall_modes),
    log:
        f"{CONTACT_DIR}/logs/contact_hoop_profile.log",
    shell:
        "capsule-cli contact --model hoop --speed-mm-s {params.speeds} --wall-mode {params.walls} "
        "--params {input.params} --out {output.table} --profile-out {output.profile} --quiet > {log} 2>&1"


rule contact_end_shape:
    input:
        params=CONTACT_PARAMS,
        code=CONTACT_PKG,
    output:
        table=f"{CONTACT_DIR}/end_shape.parquet",
        profile=f"{CONTACT_DIR}/end_shape_profile.parquet",
    params:
        speed=f"{C_CONTACT.end_shape_speed_mm_s:g}",
        ends=_csv(C_CONTACT.end_lengths_mm),
        walls=",".join(C_CONTACT.wall_modes),
    log:
        f"{CONTACT_DIR}/logs/contact_end_shape.log",
    shell:
        "capsule-cli contact --model hoop --speed-mm-s {params.speed} --end-length-mm {params.ends} "
        "--wall-mode {params.walls} --params {input.params} --out {output.table} "
        "--profile-out {output.profile} --quiet > {log} 2>&1"


rule contact_figure_speed:
    input:
        table=rules.contact_cases_vs_speed.output.table,
        reference=rules.contact_reference.output.table,
        code=CONTACT_PLOT_PKG,
    output:
        figure=captioned(f"{CONTACT_DIR}/pressure_vs_speed.png", "contact_pressure_vs_speed", CAT_CONTACT,
                         "Cases 1-3 over speed (seed 003 Figs 15, 17, 19)"),
    log:
        f"{CONTACT_DIR}/logs/contact_figure_speed.log",
    shell:
        "capsule-cli contact-plot speed --table {input.table} --reference {input.reference} "
        "--out {output.figure} --quiet > {log} 2>&1"


rule contact_figure_hoop_speed:
    input:
        table=rules.contact_hoop_vs_speed.output.table,
        code=CONTACT_PLOT_PKG,
    output:
        figure=captioned(f"{CONTACT_DIR}/hoop_vs_speed.png", "contact_hoop_vs_speed", CAT_CONTACT,
                         "Hoop pressure over speed and R_i (seed 003 eq 14)"),
    log:
        f"{CONTACT_DIR}/logs/contact_figure_hoop_speed.log",
    shell:
        "capsule-cli contact-plot hoop-speed --table {input.table} --out {output.figure} --quiet > {log} 2>&1"


rule contact_figure_radius:
    input:
        table=rules.contact_hoop_vs_radius.output.table,
        reference=rules.contact_reference.output.table,
        code=CONTACT_PLOT_PKG,
    output:
        figure=captioned(f"{CONTACT_DIR}/hoop_vs_radius.png", "contact_hoop_vs_radius", CAT_CONTACT,
                         "Hoop pressure over speed and R_i (seed 003 eq 14)"),
    log:
        f"{CONTACT_DIR}/logs/contact_figure_radius.log",
    shell:
        "capsule-cli contact-plot radius --table {input.table} --reference {input.reference} "
        "--out {output.figure} --quiet > {log} 2>&1"


rule contact_figure_profile:
    input:
        table=rules.contact_hoop_profile.output.profile,
        code=CONTACT_PLOT_PKG,
    output:
        figure=captioned(f"{CONTACT_DIR}/hoop_profile.png", "contact_hoop_profile", CAT_CONTACT,
                         "Pressure along the capsule (seed 003 Fig 12)"),
    log:
        f"{CONTACT_DIR}/logs/contact_figure_profile.log",
    shell:
        "capsule-cli contact-plot profile --by speed_mm_s --table {input.table} --out {output.figure} "
        "--quiet > {log} 2>&1"


rule contact_figure_end_shape:
    input:
        table=rules.contact_end_shape.output.table,
        profile=rules.contact_end_shape.output.profile,
        reference=rules.contact_reference.output.table,
        code=CONTACT_PLOT_PKG,
    output:
        figure=captioned(f"{CONTACT_DIR}/end_shape.png", "contact_end_shape", CAT_CONTACT,
                         "End shape (seed 001 section 6, Fig 15a)"),
        profile_figure=captioned(f"{CONTACT_DIR}/end_shape_profile.png", "contact_end_shape_profile",
                                 CAT_CONTACT, "End shape (seed 001 section 6, Fig 15a)"),
    log:
        f"{CONTACT_DIR}/logs/contact_figure_end_shape.log",
    shell:
        "(capsule-cli contact-plot end-shape --table {input.table} --reference {input.reference} "
        "--out {output.figure} --quiet && "
        "capsule-cli contact-plot profile --by end_length_mm --table {input.profile} "
        "--out {output.profile_figure} --quiet) > {log} 2>&1"


if C_CONTACT.enabled:
    CONTACT_TARGETS += [
        rules.contact_reference.output.table,
        rules.contact_cases_vs_speed.output.table,
        rules.contact_hoop_vs_speed.output.table,
        rules.contact_hoop_vs_radius.output.table,
        rules.contact_hoop_profile.output.profile,
        rules.contact_end_shape.output.table,
        rules.contact_figure_speed.output.figure,
        rules.contact_figure_hoop_speed.output.figure,
        rules.contact_figure_radius.output.figure,
        rules.contact_figure_profile.output.figure,
        rules.contact_figure_end_shape.output.figure,
        rules.contact_figure_end_shape.output.profile_figure,
    ]
