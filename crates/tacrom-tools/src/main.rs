//! `tacrom`: the command-line tool (`tacrom --help`; the options are in
//! [`tacrom_tools::cli`]). Lengths on the command line are in millimetres.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

use clap::Parser;
use tacrom::config::{Config, RawConfig};
use tacrom::geometry::Placed;
use tacrom::sensor::TactileSensor;
use tacrom_tools::bench::plot::depth_image;
use tacrom_tools::bench::protocol::Indenter;
use tacrom_tools::bench::{BenchError, BenchOptions, IndenterSource};
use tacrom_tools::cli::{
    BenchArgs, CalibrateArgs, Cli, Command, CompareArgs, EvalRomArgs, GenDataArgs, MpmArgs,
    MpmPart, RenderArgs, RomFeaturesArgs, StabilityArgs,
};
use tacrom_tools::progress::Progress;

fn main() -> ExitCode {
    let result = match Cli::parse().command {
        Command::Bench(a) => bench(a),
        Command::Render(a) => render(a),
        Command::Stability(a) => stability(a),
        Command::Mpm(a) => mpm(a),
        Command::GenData(a) => gen_data(a),
        Command::EvalRom(a) => eval_rom(a),
        Command::RomFeatures(a) => rom_features(a),
        Command::Calibrate(a) => calibrate(a),
        Command::Compare(a) => compare(a),
        Command::DocTables(a) => doc_tables(a),
        Command::Probe(a) => {
            tacrom_tools::probe::run(&a.name, a.args);
            Ok(())
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("tacrom: error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn default_indenters() -> PathBuf {
    tacrom::pattern_dir()
}

fn bench(a: BenchArgs) -> Result<(), BenchError> {
    let dir = default_indenters();
    let mut o = if a.quick {
        BenchOptions::quick(dir)
    } else {
        BenchOptions::full(dir)
    };
    let IndenterSource::Folder {
        dir,
        scale,
        flip,
        names,
        limit,
    } = &mut o.indenters
    else {
        unreachable!("the profiles read a folder")
    };
    if let Some(d) = a.indenters {
        *dir = d;
        // Another folder: its own meshes, not the profile's selection.
        names.clear();
    }
    if let Some(s) = a.scale {
        *scale = s;
    }
    *flip &= !a.no_flip;
    if !a.only.is_empty() {
        *names = a.only;
    }
    if a.limit.is_some() {
        *limit = a.limit;
    }
    o.grid = a.grid.unwrap_or(o.grid);
    o.spacing = a.spacing.unwrap_or(o.spacing);
    if !a.depths.is_empty() {
        o.depths = a.depths;
    }
    if !a.modes.is_empty() {
        o.modes = a.modes;
    }
    o.reference_dx = a.reference_dx.unwrap_or(o.reference_dx);
    o.reference_threads = a.reference_threads.unwrap_or(o.reference_threads);
    if !a.threads.is_empty() {
        o.threads = a.threads;
    }
    o.resolution = a.resolution.unwrap_or(o.resolution);
    o.attrs = a.attrs;
    if a.no_cache {
        o.cache = None;
    } else if a.cache.is_some() {
        o.cache = a.cache;
    }
    o.out = a
        .out
        .unwrap_or_else(|| PathBuf::from("out/bench").join(&o.profile));
    o.panels = a.panels.unwrap_or(o.panels);
    o.progress = !a.quiet;
    o.shard = a.shard;
    o.reference_only = a.reference_only;
    o.adopt_physics = a.adopt_physics;
    let r = tacrom_tools::bench::run(&o)?;
    if o.reference_only {
        let reference = &r.rows[0];
        println!(
            "reference of shard {}/{} ({}): {} presses, {} of them already cached, in {}; \
             {:.0} s",
            o.shard.0,
            o.shard.1,
            r.indenters.join(", "),
            reference.evaluations,
            reference.cached,
            o.cache
                .as_deref()
                .map_or("-".into(), |p| p.display().to_string()),
            r.wall_seconds
        );
        return Ok(());
    }
    println!("{}", tacrom_tools::bench::report::markdown(&r));
    if let Some(path) = &a.write_baseline {
        tacrom_tools::bench::check::write_baseline(&r, path)?;
        eprintln!("baseline written to {}", path.display());
    }
    let mut failed = Vec::new();
    let checks: [(_, fn(_, _) -> _); 2] = [
        (&a.check, tacrom_tools::bench::check::check),
        (
            &a.check_full,
            tacrom_tools::bench::check::check_against_full,
        ),
    ];
    for (path, run) in checks {
        let Some(path) = path else { continue };
        let (lines, ok) = run(&r, path)?;
        println!("## Check against {}\n", path.display());
        for l in &lines {
            println!("    {l}");
        }
        if !ok {
            failed.push(path.display().to_string());
        }
    }
    if !failed.is_empty() {
        return Err(BenchError::Usage(format!(
            "the benchmark's accuracy checks against {} failed",
            failed.join(" and ")
        )));
    }
    Ok(())
}

fn render(a: RenderArgs) -> Result<(), BenchError> {
    let mut raw = RawConfig::default().with("outputs", "depth force");
    if let Some(p) = &a.physics {
        raw = raw.with("physics", p);
    }
    if let Some([w, h]) = a.resolution {
        raw = raw.with("resolution", &format!("{w} {h}"));
    }
    for (k, v) in &a.attrs {
        raw = raw.with(k, v);
    }
    let (x, y, depth, out) = (a.x, a.y, a.depth, a.out);
    let indenter = match &a.mesh {
        Some(p) => Indenter::from_mesh(p, a.scale, !a.no_flip)?,
        None => Indenter::sphere(a.radius)?,
    };
    let config = Config::from_raw("render", &raw).map_err(|e| BenchError::Config(e.to_string()))?;
    let mut sensor =
        TactileSensor::new(config.clone()).map_err(|e| BenchError::Config(e.to_string()))?;
    let mut data = vec![0.0; config.sensordata_len()];
    let placed = [Placed {
        shape: Arc::clone(&indenter.shape),
        pose: indenter.pose(x, y, depth),
    }];
    let t0 = std::time::Instant::now();
    let eval = sensor.evaluate(&placed, &mut data);
    let ms = t0.elapsed().as_secs_f64() * 1e3;
    for w in &eval.warnings {
        eprintln!("tacrom: warning: {w}");
    }
    let title = format!(
        "{} {} at ({:.1}, {:.1}) mm, depth {:.2} mm",
        config.physics.name(),
        indenter.name,
        x * 1e3,
        y * 1e3,
        depth * 1e3
    );
    let canvas = depth_image(
        &title,
        (config.width, config.height),
        config.fov,
        sensor.depth(),
    )
    .map_err(|e| BenchError::Output {
        path: out.clone(),
        message: e.to_string(),
    })?;
    if let Some(parent) = out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| BenchError::Output {
            path: parent.to_path_buf(),
            message: e.to_string(),
        })?;
    }
    canvas.save_png(&out).map_err(|e| BenchError::Output {
        path: out.clone(),
        message: e.to_string(),
    })?;
    let f = sensor.force();
    let max = sensor.depth().iter().copied().fold(0.0f64, f64::max);
    println!(
        "{}: max depth {:.1} um, force ({:.4}, {:.4}, {:.4}) N, {ms:.1} ms",
        out.display(),
        max * 1e6,
        f[0],
        f[1],
        f[2]
    );
    Ok(())
}

fn mpm(a: MpmArgs) -> Result<(), BenchError> {
    use tacrom_tools::bench::mpm::{markdown, run, MpmBenchOptions};
    let mut options = MpmBenchOptions::standard();
    if !a.dx.is_empty() {
        options.hertz_dx.clone_from(&a.dx);
        options.speed_dx = a.dx;
    }
    if !a.depths.is_empty() {
        options.depths = a.depths;
    }
    if !a.threads.is_empty() {
        options.threads = a.threads;
    }
    options.frames = a.frames.unwrap_or(options.frames);
    options.friction = a.friction.unwrap_or(options.friction);
    if !a.tolerances.is_empty() {
        options.tolerances = a.tolerances;
    }
    options.out = a.out;
    options.progress = !a.quiet;
    if !a.solver.is_empty() {
        options.solvers = a.solver;
    }
    if a.fine {
        options = options.with_fine();
    }
    let parts = [
        MpmPart::Hertz,
        MpmPart::Speed,
        MpmPart::Work,
        MpmPart::Small,
    ];
    for part in parts
        .into_iter()
        .filter(|p| a.only.is_some_and(|o| o != *p))
    {
        match part {
            MpmPart::Hertz => options.hertz_dx.clear(),
            MpmPart::Speed => options.speed_dx.clear(),
            MpmPart::Work => {
                options.youngs.clear();
                options.poissons.clear();
            }
            MpmPart::Small => options.small_depths.clear(),
        }
    }
    let result = run(&options)?;
    print!("{}", markdown(&result));
    println!("\nwritten to {}", options.out.display());
    Ok(())
}

/// A `LO,HI` range of two values (`None` for a single value or none).
fn range(v: &[f64]) -> Result<Option<[f64; 2]>, BenchError> {
    match *v {
        [lo, hi] if lo < hi => Ok(Some([lo, hi])),
        [lo, hi] => Err(BenchError::Usage(format!(
            "gen-data: a range LO,HI needs LO < HI, got {lo},{hi}"
        ))),
        _ => Ok(None),
    }
}

fn gen_data(a: GenDataArgs) -> Result<(), BenchError> {
    use tacrom_tools::datagen::{generate, GenConfig};
    let defaults = GenConfig::default();
    let config = GenConfig {
        out: a.out,
        samples: a.samples,
        shard: a.shard,
        seed: a.seed,
        coarse_dx: a.coarse_dx,
        coarse_solver: a.coarse_solver,
        fine_dx: a.fine_dx,
        pitch: a.pitch,
        threads: a.threads,
        patterns: a.patterns.unwrap_or(defaults.patterns),
        families: a.families,
        fine_max_iterations: a.fine_max_iterations,
        held_out_only: a.held_out_only,
        indices: a.indices,
        refresh_coarse: a.refresh_coarse,
        gel: tacrom::mpm::GelParams {
            poisson: a.poisson.first().copied().unwrap_or(defaults.gel.poisson),
            friction: a.friction.first().copied().unwrap_or(defaults.gel.friction),
            ..defaults.gel
        },
        poisson_range: range(&a.poisson)?,
        friction_range: range(&a.friction)?,
        gel_family: match (a.gel_family, a.gel_size.as_slice()) {
            (false, _) => None,
            (true, []) => Some(tacrom_tools::datagen::GelFamily::default()),
            (true, &[x, y, t]) => Some(
                tacrom_tools::datagen::GelFamily::default()
                    .with_gel([x, y, t].map(|v| 1e-3 * v))
                    .map_err(|e| BenchError::Usage(format!("gen-data --gel-size: {e}")))?,
            ),
            (true, other) => {
                return Err(BenchError::Usage(format!(
                    "gen-data --gel-size takes X,Y,T in mm, got {other:?}"
                )))
            }
        },
    };
    let [p0, p1] = config.poisson_range.unwrap_or([config.gel.poisson; 2]);
    let [f0, f1] = config.friction_range.unwrap_or([config.gel.friction; 2]);
    for (poisson, friction) in [(p0, f0), (p1, f1)] {
        let gel = tacrom::mpm::GelParams {
            poisson,
            friction,
            ..config.gel
        };
        tacrom::mpm::Gel::validate(&gel, &Default::default())
            .map_err(|e| BenchError::Usage(format!("gen-data: {e}")))?;
    }
    if a.list {
        for line in tacrom_tools::datagen::list(&config).map_err(BenchError::Usage)? {
            println!("{line}");
        }
        return Ok(());
    }
    let summary = generate(&config, |line| eprintln!("{line}")).map_err(BenchError::Usage)?;
    eprintln!("{summary}");
    Ok(())
}

fn eval_rom(a: EvalRomArgs) -> Result<(), BenchError> {
    use tacrom_tools::bench::heldout::{markdown, run, EvalOptions};
    let models = if a.models.is_empty() {
        let shipped = ["rom-default", "rom-latent16", "rom-no-multiscale"];
        tacrom::rom::default_model_dir()
            .and_then(|d| {
                d.parent()
                    .map(|p| shipped.iter().map(|m| p.join(m)).collect::<Vec<_>>())
            })
            .unwrap_or_default()
            .into_iter()
            .filter(|m| m.is_dir())
            .collect()
    } else {
        a.models
    };
    let options = EvalOptions {
        data: a.data,
        models,
        all: a.all,
        refined: a.refined,
        compare: a.compare,
        out: a.out,
    };
    let result = run(&options)?;
    print!("{}", markdown(&result));
    println!("\nwritten to {}", options.out.display());
    Ok(())
}

fn rom_features(a: RomFeaturesArgs) -> Result<(), BenchError> {
    use tacrom_tools::rom_features::{write, FeaturesConfig};
    let model = match a.model {
        Some(m) => m,
        None => tacrom::rom::default_model_dir().ok_or_else(|| {
            BenchError::Usage(format!(
                "the shipped model models/{} was not found; pass --model DIR",
                tacrom::rom::DEFAULT_MODEL
            ))
        })?,
    };
    let config = FeaturesConfig {
        out: a.out,
        model,
        threads: a.threads,
    };
    println!("{}", write(&config).map_err(BenchError::Usage)?);
    Ok(())
}

fn doc_tables(a: tacrom_tools::cli::DocTablesArgs) -> Result<(), BenchError> {
    let path = a
        .readme
        .unwrap_or_else(|| tacrom::checkout_root().join("README.md"));
    let io = |e: std::io::Error| BenchError::Usage(format!("{}: {e}", path.display()));
    let text = std::fs::read_to_string(&path).map_err(io)?;
    let spliced = tacrom_tools::doc_tables::splice(&text)
        .map_err(|e| BenchError::Usage(format!("{}: {e}", path.display())))?;
    if a.write {
        if spliced != text {
            std::fs::write(&path, spliced).map_err(io)?;
        }
        println!("{}: tables written", path.display());
        Ok(())
    } else if spliced == text {
        println!("{}: tables up to date", path.display());
        Ok(())
    } else {
        Err(BenchError::Usage(format!(
            "{}: tables differ from the code's; run `tacrom doc-tables --write`",
            path.display()
        )))
    }
}

fn calibrate(a: CalibrateArgs) -> Result<(), BenchError> {
    use tacrom_tools::calibrate::{self as cal, fit::FitOptions, synth};
    let usage = |e: cal::CalibrateError| BenchError::Usage(e.to_string());
    if let Some(out) = a.synthesize {
        let o = synth::SynthOptions {
            presses: a.presses,
            resolution: a.resolution,
            pixel_size: a.pixel_size,
            seed: a.seed,
            with_contact: !a.no_contact,
            ..synth::SynthOptions::new(out.clone())
        };
        let presses = synth::synthesize(&o).map_err(usage)?;
        println!(
            "{}: background.png, {} presses of {} x {} pixels of {} mm, {}",
            out.display(),
            presses.len(),
            o.resolution[0],
            o.resolution[1],
            o.pixel_size * 1e3,
            cal::PRESS_LIST
        );
        return Ok(());
    }
    let input = a.input.expect("clap requires DIR without --synthesize");
    let mut o = cal::CalibrateOptions::new(input);
    if let Some(out) = a.out {
        o.out = out;
    }
    o.fit = FitOptions {
        bins: a.bins,
        range: a.range,
        smooth: a.smooth,
    };
    o.holdout = a.holdout;
    o.edge_margin = a.edge_margin;
    o.threshold = a.threshold;
    o.mirror = a.mirror;
    o.detect = a.detect;
    if a.gel {
        let mut search = cal::gel::GelSearch {
            threads: a.threads,
            dx: a.dx.map(|d| d * 1e-3),
            ..Default::default()
        };
        if !a.thickness.is_empty() {
            search.thicknesses = a.thickness.iter().map(|t| t * 1e-3).collect();
        }
        if !a.poisson.is_empty() {
            search.poissons = a.poisson;
        }
        search.blurs = a.blur.iter().map(|b| b * 1e-3).collect();
        o.gel = Some(search);
    }
    let report = cal::calibrate(&o).map_err(usage)?;
    print!("{}", cal::markdown(&report));
    Ok(())
}

fn compare(a: CompareArgs) -> Result<(), BenchError> {
    use tacrom_tools::calibrate::compare::{self as cmp, Row};
    let usage = BenchError::Usage;
    let mut rows = if a.rows.is_empty() || a.with_defaults {
        Row::defaults()
    } else {
        Vec::new()
    };
    for spec in &a.rows {
        rows.push(Row::parse(spec).map_err(usage)?);
    }
    let sensor = tacrom::sensor_file::locate(&a.sensor)
        .map_err(|e| usage(format!("--sensor {}: {e}", a.sensor)))?;
    let o = cmp::CompareOptions {
        input: a.input,
        sensor,
        holdout: a.holdout,
        mirror: a.mirror,
        detect: a.detect,
        threshold: a.threshold,
        rows,
        threads: a.threads,
        figure_presses: if a.figure.is_some() {
            a.figure_presses
        } else {
            0
        },
    };
    let (table, figure) = cmp::compare_with_figure(&o).map_err(|e| usage(e.to_string()))?;
    if let Some(path) = &a.figure {
        figure.write(path, 160).map_err(|e| usage(e.to_string()))?;
        println!("Figure: {} ({})", path.display(), figure.labels.join(" | "));
    }
    print!("{}", cmp::markdown(&table));
    let json = serde_json::to_string_pretty(&table).expect("a table of numbers and text");
    if let Some(path) = &a.json {
        std::fs::write(path, json + "\n").map_err(|e| usage(format!("{}: {e}", path.display())))?;
    }
    if let Some(path) = &a.baseline {
        let text =
            std::fs::read_to_string(path).map_err(|e| usage(format!("{}: {e}", path.display())))?;
        let baseline: cmp::Table =
            serde_json::from_str(&text).map_err(|e| usage(format!("{}: {e}", path.display())))?;
        let worse = cmp::regressions(&table, &baseline, a.tolerance);
        if !worse.is_empty() {
            return Err(usage(format!(
                "worse than {}:\n  {}",
                path.display(),
                worse.join("\n  ")
            )));
        }
        println!(
            "\nNo row worse than {} by more than {}.",
            path.display(),
            a.tolerance
        );
    }
    Ok(())
}

fn stability(a: StabilityArgs) -> Result<(), BenchError> {
    let (modes, dx) = (a.physics, a.dx);
    let cases =
        tacrom_tools::stability::cases(Some(&tacrom::pattern_dir())).map_err(BenchError::Usage)?;
    let progress = Progress::new(modes.len() * cases.len(), true);
    let mut failed = 0;
    for mode in &modes {
        let mut raw = RawConfig::default().with("physics", mode);
        if let Some(dx) = dx {
            raw = raw.with("dx", &dx.to_string());
        }
        if let Some(solver) = a.solver {
            raw = raw.with("solver", solver.name());
        }
        if let Some(model) = &a.model {
            raw = raw.with("model", &model.display().to_string());
        }
        Config::from_raw("stability", &raw).map_err(|e| BenchError::Config(e.to_string()))?;
        let rows: Vec<_> = cases
            .iter()
            .map(|case| {
                progress.message(format!("{mode}: {}", case.name));
                let row = tacrom_tools::stability::run_case(case, &raw);
                progress.advance(1);
                progress.line(&format!(
                    "  {mode}: {} {}",
                    row.name,
                    if row.ok() { "ok" } else { "FAIL" }
                ));
                row
            })
            .collect();
        failed += rows.iter().filter(|r| !r.ok()).count();
        progress.suspend(|| {
            println!(
                "\n### physics = {mode}\n\n{}",
                tacrom_tools::stability::table(&rows)
            )
        });
    }
    progress.finish();
    if failed > 0 {
        return Err(BenchError::Usage(format!(
            "{failed} stability case(s) failed"
        )));
    }
    Ok(())
}
