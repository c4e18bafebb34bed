# Rules of the dynamics stage (wiring only: every rule calls capsule-cli).
# Appends its final outputs to DYNAMICS_TARGETS when config["dynamics"]["enabled"].
# Settings: capsule_cli/schemas/dynamics.py (DynamicsStudy), validated as STUDY.dynamics.

DYN = STUDY.dynamics
DYN_DIR = f"{RESULTS}/dynamics"
DYN_PKG = pkg("dynamics/engine.py", "dynamics/model.py", "dynamics/run.py", "dynamics/sweep.py",
              "dynamics/parallel.py", "steps/dynamics.py", "cli/dynamics.py")
DYN_CASES = {c.label: c for c in DYN.frequency_sweeps.cases}
DYN_DUTY_F = [f"{f:g}" for f in DYN.duty_map.f_Hz]


def _fric_args(kind, Pf_N, speed_unit="mm/s"):
    return (f"--friction {kind}" + (f" --Pf-N {Pf_N}" if kind == "coulomb" else "")
            + (f" --law-speed-unit {speed_unit}" if speed_unit != "mm/s" else ""))


rule dynamics_sweep_f:
    """Frequency sweep for one friction case and protocol (seed 000 Figs 17-18)."""
    input:
        DYN_PKG,
        params=str(CONFIGS / "params" / f"{DYN.frequency_sweeps.model}.yaml"),
        laws=str(CONFIGS / "params" / "friction_laws_dynamics.yaml"),
    output:
        directory(f"{DYN_DIR}/sweeps/{{case}}_{{protocol}}"),
    params:
        fs=DYN.frequency_sweeps.model_dump(),
        fric=lambda wc: _fric_args(DYN_CASES[wc.case].friction, DYN_CASES[wc.case].Pf_N,
                                   DYN_CASES[wc.case].law_speed_unit),
    log:
        f"{DYN_DIR}/logs/sweep_{{case}}_{{protocol}}.log",
    benchmark:
        f"{DYN_DIR}/benchmarks/sweep_{{case}}_{{protocol}}.tsv"
    wildcard_constraints:
        protocol="rest|up|down",
    shell:
        "capsule-cli sweep --quiet --out {output} --model {params.fs[model]} --param f_Hz "
        "--start {params.fs[f_start_Hz]} --stop {params.fs[f_stop_Hz]} --num {params.fs[f_num]} "
        "--protocol {wildcards.protocol} --Pd-N {params.fs[Pd_N]} {params.fric} "
        "--transient-periods {params.fs[transient_periods]} --periods {params.fs[recorded_periods]} "
        "--label {wildcards.case} > {log} 2>&1"


rule dynamics_sweep_duty:
    """Duty sweep of the square-wave drive at one frequency (seed 004 Scenario 3)."""
    input:
        DYN_PKG,
        params=str(CONFIGS / "params" / f"{DYN.duty_map.model}.yaml"),
        laws=str(CONFIGS / "params" / "friction_laws_dynamics.yaml"),
    output:
        directory(f"{DYN_DIR}/duty/f{{f}}"),
    params:
        dm=DYN.duty_map.model_dump(),
        fric=_fric_args(DYN.duty_map.friction, DYN.duty_map.Pf_N),
    log:
        f"{DYN_DIR}/logs/duty_f{{f}}.log",
    benchmark:
        f"{DYN_DIR}/benchmarks/duty_f{{f}}.tsv"
    shell:
        "capsule-cli sweep --quiet --out {output} --model {params.dm[model]} --waveform square --param duty "
        "--start {params.dm[duty_start]} --stop {params.dm[duty_stop]} --num {params.dm[duty_num]} "
        "--f-Hz {wildcards.f} --Pd-N {params.dm[Pd_N]} {params.fric} --protocol {params.dm[protocol]} "
        "--transient-periods {params.dm[transient_periods]} --periods {params.dm[recorded_periods]} "
        "--label duty_f{wildcards.f} > {log} 2>&1"


# Magnification maps, split into jobs sized from the measured cost per period (config
# dynamics.magnify.cost_us_per_period, target_job_s): large maps along P_d (every job runs the
# whole f axis, so continuation protocols give the same result), tiny maps grouped into one job.
from capsule_cli.steps.dynamics import plan_magnify_jobs

DYN_MG = DYN.magnify
DYN_MG_FRICTIONS = [f"{p:g}" for p in DYN_MG.Pf_N] + list(DYN_MG.laws)
DYN_MG_JOBS = {j["name"]: j for j in plan_magnify_jobs(
    DYN_MG_FRICTIONS, DYN_MG.Pd_num, DYN_MG.f_num, DYN_MG.transient_periods + DYN_MG.recorded_periods,
    DYN_MG.cost_us_per_period, DYN_MG.target_job_s, DYN_MG.threads_per_job)}


def _mg_fric_args(labels):
    return " ".join(f"--law {x}" if x in ("eq22", "eq23") else f"--Pf-N {x}" for x in labels)


rule dynamics_magnify_chunk:
    """One magnify job: some frictions over a range of P_d rows (seed 000 eq 24, Fig 19)."""
    input:
        DYN_PKG,
        params=str(CONFIGS / "params" / f"{DYN_MG.model}.yaml"),
        laws=str(CONFIGS / "params" / "friction_laws_dynamics.yaml"),
    output:
        f"{DYN_DIR}/magnify_chunks/{{job}}.parquet",
    params:
        mg=DYN_MG.model_dump(),
        fric=lambda wc: _mg_fric_args(DYN_MG_JOBS[wc.job]["frictions"]),
        rows=lambda wc: "{}:{}".format(*DYN_MG_JOBS[wc.job]["rows"]),
    threads: DYN_MG.threads_per_job
    resources:
        runtime=lambda wc: max(10, int(3 * DYN_MG_JOBS[wc.job]["est_s"] / 60) + 5),  # minutes, 3x the estimate
        mem_mb=2000,
    wildcard_constraints:
        job="job[0-9]+",
    log:
        f"{DYN_DIR}/logs/magnify_{{job}}.log",
    benchmark:
        f"{DYN_DIR}/benchmarks/magnify_{{job}}.tsv"
    shell:
        "NUMBA_NUM_THREADS={threads} capsule-cli magnify --quiet --out {output} --model {params.mg[model]} "
        "{params.fric} --Pd-rows {params.rows} "
        "--Pd-start-N {params.mg[Pd_start_N]} --Pd-stop-N {params.mg[Pd_stop_N]} --Pd-num {params.mg[Pd_num]} "
        "--f-start-Hz {params.mg[f_start_Hz]} --f-stop-Hz {params.mg[f_stop_Hz]} --f-num {params.mg[f_num]} "
        "--protocol {params.mg[protocol]} --transient-periods {params.mg[transient_periods]} "
        "--periods {params.mg[recorded_periods]} > {log} 2>&1"


rule dynamics_magnify:
    """Gather the magnify jobs into one table (rows as an unchunked run)."""
    input:
        chunks=[f"{DYN_DIR}/magnify_chunks/{j}.parquet" for j in DYN_MG_JOBS],
    output:
        f"{DYN_DIR}/magnify.parquet",
    params:
        fric=_mg_fric_args(DYN_MG_FRICTIONS),
        chunks=lambda wc, input: " ".join(f"--gather {c}" for c in input.chunks),
    localrule: True
    log:
        f"{DYN_DIR}/logs/magnify_gather.log",
    shell:
        "capsule-cli magnify --quiet --out {output} {params.fric} {params.chunks} > {log} 2>&1"


DYN_SWEEPS = [(label, c.figure, prot) for label, c in DYN_CASES.items() for prot in DYN.frequency_sweeps.protocols]
DYN_MAGNIFY = [f"{DYN_DIR}/magnify.parquet"] if DYN.magnify.enabled else []


rule dynamics_report:
    """Landmark table beside seed 000 section 5.3, Figs 17-18 per protocol, duty map, A_f maps."""
    input:
        sweeps=[f"{DYN_DIR}/sweeps/{l}_{p}" for l, _, p in DYN_SWEEPS],
        duty=[f"{DYN_DIR}/duty/f{f}" for f in DYN_DUTY_F],
        magnify=DYN_MAGNIFY,
        code=pkg("plots/dynamics.py", "steps/dynamics.py"),
    output:
        landmarks=f"{DYN_DIR}/report/landmarks.parquet",
        table=captioned(f"{DYN_DIR}/report/landmarks.md", "dynamics_landmarks", CAT_DYNAMICS,
                        "Landmarks beside seed 000 section 5.3"),
        duty_map=captioned(f"{DYN_DIR}/report/duty_map.png", "dynamics_duty_map", CAT_DYNAMICS,
                           "Square-wave frequency x duty map (seed 004 Scenario 3)"),
        duty_table=captioned(f"{DYN_DIR}/report/duty_map.md", "dynamics_duty_map", CAT_DYNAMICS,
                             "Square-wave frequency x duty map (seed 004 Scenario 3)"),
        figs=[captioned(f"{DYN_DIR}/report/{fig}_{p}.png", "dynamics_bifurcation", CAT_DYNAMICS,
                        f"Seed 000 Fig {fig[-2:]}: bifurcation and progression", protocol=p)
              for fig in sorted({c.figure for c in DYN_CASES.values()}) for p in DYN.frequency_sweeps.protocols],
        magnify_fig=[captioned(f"{DYN_DIR}/report/magnify.png", "dynamics_magnify", CAT_DYNAMICS,
                               "Magnification factor A_f (seed 000 eq 24, Fig 19)")] if DYN_MAGNIFY else [],
    params:
        sweeps=" ".join(f"--sweep {l}:{fig}:{p}:{DYN_DIR}/sweeps/{l}_{p}" for l, fig, p in DYN_SWEEPS),
        duty=" ".join(f"--duty-sweep {DYN_DIR}/duty/f{f}" for f in DYN_DUTY_F),
        magnify=" ".join(f"--magnify {m}" for m in DYN_MAGNIFY),
        outdir=f"{DYN_DIR}/report",
    log:
        f"{DYN_DIR}/logs/report.log",
    shell:
        "capsule-cli dynamics-report --quiet --out {params.outdir} {params.sweeps} {params.duty} {params.magnify} "
        "> {log} 2>&1"


rule dynamics_bench:
    """Benchmark of the engine against solve_ivp (contract section 6)."""
    input:
        DYN_PKG,
        pkg("dynamics/bench.py", "dynamics/reference.py"),
    output:
        f"{DYN_DIR}/bench.json",
    log:
        f"{DYN_DIR}/logs/bench.log",
    shell:
        "capsule-cli bench --quiet --out {output} > {log} 2>&1"


if DYN.enabled:
    DYNAMICS_TARGETS += rules.dynamics_report.output
    if DYN.bench:
        DYNAMICS_TARGETS += [f"{DYN_DIR}/bench.json"]
