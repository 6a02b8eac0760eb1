//! The benchmark's report: `report.md` (tables a person reads at a glance), `results.csv`
//! (one row per mode and thread count), `groups.csv` (each mode's errors per depth and per
//! indenter), `error_vs_time.png`, `error_vs_depth.png` and `panels/*.png`.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use super::plot::{
    DepthPlot, DepthSeries, ErrorTimePlot, Marker, Panel, PanelImage, PlotPoint, PALETTE,
};
use super::{metrics, BenchError, BenchResult, Frames, ModeResult, STAGES};
use tacrom::geometry::PixelGrid;

/// What the figures are drawn from.
pub struct Figures<'a> {
    /// The image grid.
    pub grid: &'a PixelGrid,
    /// The reference's frames.
    pub reference: &'a Frames,
    /// Each mode's frames (its first thread count).
    pub modes: &'a [(String, Frames)],
}

fn num(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:.digits$}")
    } else {
        "-".to_owned()
    }
}

fn mib(v: Option<u64>) -> String {
    v.map_or("-".to_owned(), |b| {
        format!("{:.0}", b as f64 / (1 << 20) as f64)
    })
}

fn speedup(rows: &[ModeResult], r: &ModeResult) -> String {
    if r.threads == 1 {
        return "1.00".to_owned();
    }
    rows.iter()
        .find(|o| o.label == r.label && o.threads == 1)
        .map_or("-".to_owned(), |o| num(o.median_ms / r.median_ms, 2))
}

/// The headline table (each mode: depth MAE, SSIM, force error, median and p90 ms per
/// evaluation at one and at two threads) and the per-interaction table after the paper's
/// Table II (time per press sequence, peak memory, Chamfer-L2; one thread).
fn headline(s: &mut String, r: &BenchResult) {
    let at = |label: &str, threads: usize| {
        r.rows
            .iter()
            .find(|m| !m.reference && m.label == label && m.threads == threads)
    };
    let ms = |m: Option<&ModeResult>| {
        m.map_or(["-".to_owned(), "-".to_owned()], |m| {
            [num(m.median_ms, 2), num(m.p90_ms, 2)]
        })
    };
    let first = |m: &&ModeResult| !m.reference && m.thread_diff.is_none();
    let _ = writeln!(
        s,
        "## Headline\n\n| mode | depth MAE um | SSIM | force err % | median ms, 1 thread | \
         p90 ms, 1 thread | median ms, 2 threads | p90 ms, 2 threads |\n\
         |---|---:|---:|---:|---:|---:|---:|---:|"
    );
    for m in r.rows.iter().filter(first) {
        let (one, two) = (ms(at(&m.label, 1)), ms(at(&m.label, 2)));
        let a = &m.accuracy;
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} |",
            m.label,
            num(a.mae * 1e6, 2),
            num(a.ssim, 4),
            num(a.force_rel * 100.0, 1),
            one[0],
            one[1],
            two[0],
            two[1]
        );
    }
    let _ = writeln!(
        s,
        "\n## Per interaction (after the paper's Table II)\n\nOne indenter pressed at one \
         position through every depth; the first thread count of each mode; this CPU.\n\n\
         | mode | s per sequence | memory MiB | Chamfer-L2 um^2 |\n|---|---:|---:|---:|"
    );
    let reference = r.rows.iter().filter(|m| m.reference);
    for m in reference.chain(r.rows.iter().filter(first)) {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} |",
            m.label,
            num(m.sequence_s, 2),
            m.own_rss.map_or_else(
                || format!("{} (process peak)", mib(m.peak_rss)),
                |b| mib(Some(b))
            ),
            if m.reference {
                "0 (reference)".to_owned()
            } else {
                num(m.accuracy.chamfer * 1e12, 2)
            }
        );
    }
    let _ = writeln!(
        s,
        "\nMemory: the mode's own, the peak resident set during its run above the start \
         (free heap pages handed back first, the indenters' distance grids built before), \
         less the images the benchmark keeps; the first rom-type mode also holds ONNX \
         Runtime's one-time start. A reference read from the cache gives the peak of the \
         process that computed it."
    );
    let _ = writeln!(
        s,
        "\nThe paper's Table II (full MPM, FEM+IPC, Tacchi and its own method, on a GPU) is \
         not reproduced beside these rows: only its abstract was at hand, which reports its \
         method 65 % faster than TacIPC with 40 % less memory."
    );
    s.push('\n');
}

/// Embeds the report's figures whose file name `pick` accepts, linked relative to the
/// report (they lie beside it).
fn embed(s: &mut String, r: &BenchResult, pick: impl Fn(&str) -> bool, alt: &str) {
    for f in &r.files {
        if let Some(name) = f.file_name().and_then(|n| n.to_str()).filter(|n| pick(n)) {
            let _ = writeln!(s, "![{alt}]({name})\n");
        }
    }
}

/// A duration in the unit that reads best (s, min or h).
fn duration(seconds: f64) -> String {
    if seconds < 120.0 {
        format!("{seconds:.1} s")
    } else if seconds < 7200.0 {
        format!("{:.1} min", seconds / 60.0)
    } else {
        format!("{:.2} h", seconds / 3600.0)
    }
}

/// The markdown report.
pub fn markdown(r: &BenchResult) -> String {
    let o = &r.options;
    let mut s = String::new();
    let depths: Vec<String> = o.depths.iter().map(|d| format!("{:.1}", d * 1e3)).collect();
    let _ = writeln!(
        s,
        "# tacrom bench: error against run time ({} profile)\n",
        o.profile
    );
    let _ = writeln!(
        s,
        "Reference: fine MPM at dx = {:.2} mm, {} solver thread(s){}.",
        o.reference_dx * 1e3,
        o.reference_threads,
        if (o.reference_dx - 0.3e-3).abs() > 1e-9 {
            " (cheaper than the fine mode's default 0.3 mm: errors are against this \
             reference, not the 0.3 mm one)"
        } else {
            " (the fine mode's default)"
        }
    );
    let _ = writeln!(
        s,
        "Protocol: indenters {}; {} position(s) on a {}x{} grid {:.1} mm apart; depths {} mm \
         pressed in one continuous sequence per indenter and position; {}x{} images. \
         {} evaluations per mode and thread count. Wall time {:.0} s.\n\n\
         Command: `{}`. Machine: {}.\n",
        r.indenters.join(", "),
        r.positions.len(),
        o.grid,
        o.grid,
        o.spacing * 1e3,
        depths.join(", "),
        o.resolution[0],
        o.resolution[1],
        r.indenters.len() * r.positions.len() * o.depths.len(),
        r.wall_seconds,
        r.command,
        r.machine
    );
    if let Some(reference) = r.rows.iter().find(|m| m.reference) {
        let _ = writeln!(
            s,
            "The reference's {} presses took {} of solver time ({} from the cache, their \
             times as recorded when they were computed).\n",
            reference.evaluations,
            duration(reference.total_s),
            reference.cached
        );
    }

    headline(&mut s, r);
    embed(
        &mut s,
        r,
        |name| name == "error_vs_time.png",
        "error against time",
    );
    let _ = writeln!(s, "## Accuracy against the reference (mean over presses)\n");
    let _ = writeln!(
        s,
        "| mode | MAE um | RMSE um | PSNR dB | SSIM | Chamfer-L2 um^2 | force err N | force err % |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|---:|---:|");
    let first = |r: &&ModeResult| !r.reference && r.thread_diff.is_none();
    for m in r.rows.iter().filter(first) {
        let a = &m.accuracy;
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} |",
            m.label,
            num(a.mae * 1e6, 2),
            num(a.rmse * 1e6, 2),
            num(a.psnr, 1),
            num(a.ssim, 4),
            num(a.chamfer * 1e12, 2),
            num(a.force_abs, 4),
            num(a.force_rel * 100.0, 1)
        );
    }
    let _ = writeln!(
        s,
        "\nPSNR peak: the reference image's largest depth, per press (capped at {} dB). SSIM: \
         {}x{} Gaussian window, sigma {}, K1 = {}, K2 = {}, L = the same peak, valid windows \
         only. Chamfer-L2: sum of both directed mean squared nearest distances between the \
         deformed surfaces (every pixel centre lowered by its depth). Force error: norm of \
         the total-force difference; % of the reference's total.\n",
        metrics::PSNR_CAP_DB,
        metrics::SSIM_WINDOW,
        metrics::SSIM_WINDOW,
        metrics::SSIM_SIGMA,
        metrics::SSIM_K1,
        metrics::SSIM_K2
    );

    let modes: Vec<&ModeResult> = r.rows.iter().filter(first).collect();
    if o.depths.len() > 1 && modes.iter().any(|m| m.by_depth.len() == o.depths.len()) {
        let _ = writeln!(
            s,
            "## Per depth of the sequences: depth MAE um / force error %\n\n\
             `error_vs_depth.png` draws the MAE.\n"
        );
        embed(
            &mut s,
            r,
            |name| name == "error_vs_depth.png",
            "error against depth",
        );
        let _ = writeln!(
            s,
            "| mode | {} |",
            depths
                .iter()
                .map(|d| format!("{d} mm"))
                .collect::<Vec<_>>()
                .join(" | ")
        );
        let _ = writeln!(s, "|---|{}", "---:|".repeat(depths.len()));
        for m in &modes {
            let cells: Vec<String> = m
                .by_depth
                .iter()
                .map(|a| format!("{} / {}", num(a.mae * 1e6, 2), num(a.force_rel * 100.0, 1)))
                .collect();
            let _ = writeln!(s, "| {} | {} |", m.label, cells.join(" | "));
        }
        s.push('\n');
    }
    if r.indenters.len() > 1
        && modes
            .iter()
            .any(|m| m.by_indenter.len() == r.indenters.len())
    {
        let _ = writeln!(s, "## Per indenter: depth MAE um\n");
        let labels: Vec<&str> = modes.iter().map(|m| m.label.as_str()).collect();
        let _ = writeln!(s, "| indenter | {} |", labels.join(" | "));
        let _ = writeln!(s, "|---|{}", "---:|".repeat(labels.len()));
        for (i, name) in r.indenters.iter().enumerate() {
            let cells: Vec<String> = modes
                .iter()
                .map(|m| {
                    m.by_indenter
                        .get(i)
                        .map_or("-".to_owned(), |a| num(a.mae * 1e6, 2))
                })
                .collect();
            let _ = writeln!(s, "| {name} | {} |", cells.join(" | "));
        }
        s.push('\n');
    }

    let _ = writeln!(s, "## Cost per evaluation\n");
    let _ = writeln!(
        s,
        "| mode | threads | median ms | p90 ms | s per sequence | speed-up vs 1 thread | own MiB | peak RSS MiB | RSS at start MiB | not converged | note |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|");
    for m in &r.rows {
        let note = if m.reference {
            if m.cached == m.evaluations {
                "reference; all from cache (times of the run that computed them)".to_owned()
            } else if m.cached > 0 {
                format!("reference; {} of {} from cache", m.cached, m.evaluations)
            } else {
                "reference".to_owned()
            }
        } else {
            match m.thread_diff {
                Some(0.0) => "images identical to 1 thread".to_owned(),
                Some(d) => format!("images differ from 1 thread by up to {:.3} um", d * 1e6),
                None => String::new(),
            }
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {}/{} | {} |",
            m.label,
            m.threads,
            num(m.median_ms, 2),
            num(m.p90_ms, 2),
            num(m.sequence_s, 2),
            if m.reference {
                "-".to_owned()
            } else {
                speedup(&r.rows, m)
            },
            mib(m.own_rss),
            mib(m.peak_rss),
            mib(m.base_rss),
            m.not_converged,
            m.evaluations,
            note
        );
    }
    let _ = writeln!(
        s,
        "\ns per sequence: the median time of one indenter pressed at one position through \
         every depth (the paper's time per interaction).\n\nPeak RSS: {}; it includes what \
         the process held at the start (the next column). Own: the peak above the start, \
         less the images the benchmark keeps of the run.\n",
        if r.peak_reset {
            "VmHWM of /proc/self/status, reset before each run through /proc/self/clear_refs"
        } else {
            "VmHWM of /proc/self/status; the reset was refused, so it is the process's peak \
             so far"
        }
    );

    let _ = writeln!(s, "## Time per stage (median ms per evaluation)\n");
    let _ = writeln!(s, "| mode | threads | {} |", STAGES.join(" | "));
    let _ = writeln!(s, "|---|---:|{}", "---:|".repeat(STAGES.len()));
    for m in &r.rows {
        let cells: Vec<String> = m.stages_ms.iter().map(|v| num(*v, 3)).collect();
        let _ = writeln!(s, "| {} | {} | {} |", m.label, m.threads, cells.join(" | "));
    }
    let _ = writeln!(
        s,
        "\nscene: posing the indenters in the sensor frame; SDF: contact test and the \
         indenters' rigid surface; MPM: the gel solve (the rigid mode's penetration for \
         rigid); encoder, refinement (L-BFGS on the latent), decoder: the rom stages, \
         empty for the other modes; render: writing the outputs.\n"
    );
    if !r.unavailable.is_empty() {
        let _ = writeln!(s, "## Modes not available in this build\n");
        for (m, why) in &r.unavailable {
            let _ = writeln!(s, "* `{m}`: {why}");
        }
        s.push('\n');
    }
    if r.files
        .iter()
        .any(|f| f.parent().and_then(Path::file_name) == Some("panels".as_ref()))
    {
        let _ = writeln!(
            s,
            "## Panels\n\nReference, each mode and its error map for a few presses (`panels/`).\n"
        );
        for f in &r.files {
            if f.parent().and_then(Path::file_name) == Some("panels".as_ref()) {
                if let Some(name) = f.file_name().and_then(|n| n.to_str()) {
                    let _ = writeln!(s, "![{name}](panels/{name})\n");
                }
            }
        }
    }
    if !r.files.is_empty() {
        let _ = writeln!(s, "## Files\n");
        for f in &r.files {
            let _ = writeln!(s, "* {}", f.display());
        }
    }
    s
}

/// The CSV: one row per mode and thread count.
pub fn csv(r: &BenchResult) -> String {
    let mut s = String::from(
        "mode,threads,reference,mae_um,rmse_um,psnr_db,ssim,chamfer_um2,force_err_n,force_err_rel,\
         median_ms,p90_ms,speedup,peak_rss_mib,start_rss_mib,not_converged,evaluations,cached,\
         own_mib",
    );
    for st in STAGES {
        let _ = write!(s, ",{}_ms", st.to_lowercase());
    }
    s.push_str(",sequence_s\n");
    for m in &r.rows {
        let a = &m.accuracy;
        let _ = write!(
            s,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            m.label,
            m.threads,
            m.reference,
            num(a.mae * 1e6, 4),
            num(a.rmse * 1e6, 4),
            num(a.psnr, 3),
            num(a.ssim, 5),
            num(a.chamfer * 1e12, 4),
            num(a.force_abs, 6),
            num(a.force_rel, 5),
            num(m.median_ms, 3),
            num(m.p90_ms, 3),
            if m.reference {
                "-".to_owned()
            } else {
                speedup(&r.rows, m)
            },
            mib(m.peak_rss),
            mib(m.base_rss),
            m.not_converged,
            m.evaluations,
            m.cached
        );
        let _ = write!(s, ",{}", mib(m.own_rss));
        for v in &m.stages_ms {
            let _ = write!(s, ",{}", num(*v, 4));
        }
        let _ = writeln!(s, ",{}", num(m.sequence_s, 4));
    }
    s
}

fn write_text(path: &Path, text: &str) -> Result<(), BenchError> {
    std::fs::write(path, text).map_err(|e| BenchError::Output {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

fn png_error<E: std::fmt::Display>(path: &Path) -> impl FnOnce(E) -> BenchError + '_ {
    move |e| BenchError::Output {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// The error-time plot of a result.
pub fn error_plot(r: &BenchResult) -> ErrorTimePlot {
    let labels: Vec<&str> = {
        let mut v: Vec<&str> = Vec::new();
        for m in r.rows.iter().filter(|m| !m.reference) {
            if !v.contains(&m.label.as_str()) {
                v.push(&m.label);
            }
        }
        v
    };
    let points = r
        .rows
        .iter()
        .filter(|m| !m.reference)
        .map(|m| {
            let i = labels.iter().position(|l| *l == m.label).unwrap_or(0);
            PlotPoint {
                label: m.label.clone(),
                x: m.median_ms,
                y: m.accuracy.mae * 1e6,
                colour: PALETTE[i % PALETTE.len()],
                marker: Marker::ALL[i % Marker::ALL.len()],
                threads: m.threads,
            }
        })
        .collect();
    let reference = r.rows.iter().find(|m| m.reference).map(|m| {
        (
            m.median_ms,
            format!(
                "reference: fine dx {:.2} mm, x{}",
                r.options.reference_dx * 1e3,
                m.threads
            ),
        )
    });
    ErrorTimePlot {
        title: format!(
            "depth MAE against the fine reference ({} profile)",
            r.options.profile
        ),
        x_label: "median ms per evaluation".to_owned(),
        y_label: "depth MAE (um)".to_owned(),
        points,
        reference,
    }
}

/// Each mode's errors per depth and per indenter, one row per group: `mode, group
/// (depth or indenter), value (m or name), mae_um, rmse_um, ssim, force_err_rel`.
pub fn groups_csv(r: &BenchResult) -> String {
    let mut s = String::from("mode,group,value,mae_um,rmse_um,ssim,force_err_rel\n");
    let first = |m: &&ModeResult| !m.reference && m.thread_diff.is_none();
    for m in r.rows.iter().filter(first) {
        let depths = r.options.depths.iter().map(|d| format!("{d:e}"));
        let rows = m
            .by_depth
            .iter()
            .zip(depths)
            .map(|(a, v)| ("depth", v, a))
            .chain(
                m.by_indenter
                    .iter()
                    .zip(&r.indenters)
                    .map(|(a, v)| ("indenter", v.clone(), a)),
            );
        for (group, value, a) in rows {
            let _ = writeln!(
                s,
                "{},{group},{value},{:.4},{:.4},{:.5},{:.5}",
                m.label,
                a.mae * 1e6,
                a.rmse * 1e6,
                a.ssim,
                a.force_rel
            );
        }
    }
    s
}

/// The error-depth plot of a result: each mode's depth MAE per depth (first thread
/// count), in the colours and markers of the error-time plot.
pub fn depth_plot(r: &BenchResult) -> DepthPlot {
    let first = |m: &&ModeResult| !m.reference && m.thread_diff.is_none();
    let series = r
        .rows
        .iter()
        .filter(first)
        .enumerate()
        .map(|(i, m)| DepthSeries {
            label: m.label.clone(),
            points: r
                .options
                .depths
                .iter()
                .zip(&m.by_depth)
                .map(|(d, a)| (d * 1e3, a.mae * 1e6))
                .collect(),
            colour: PALETTE[i % PALETTE.len()],
            marker: Marker::ALL[i % Marker::ALL.len()],
        })
        .collect();
    DepthPlot {
        title: format!(
            "depth MAE per press depth ({} profile, mean over indenters and positions)",
            r.options.profile
        ),
        x_label: "press depth (mm)".to_owned(),
        y_label: "depth MAE (um)".to_owned(),
        series,
    }
}

/// The presses drawn as panels: the deepest press at the centre position of successive
/// indenters, then their middle depths.
fn panel_presses(r: &BenchResult) -> Vec<(usize, usize, usize)> {
    let centre = r
        .positions
        .iter()
        .enumerate()
        .min_by(|a, b| {
            let n = |p: &[f64; 2]| p[0] * p[0] + p[1] * p[1];
            n(a.1).total_cmp(&n(b.1))
        })
        .map_or(0, |(i, _)| i);
    let nd = r.options.depths.len();
    let mut out = Vec::new();
    for depth in [nd - 1, nd / 2] {
        for i in 0..r.indenters.len() {
            if out.len() < r.options.panels && !out.contains(&(i, centre, depth)) {
                out.push((i, centre, depth));
            }
        }
    }
    out
}

/// Writes the report's files into the output folder; returns their paths.
pub fn write(r: &BenchResult, fig: &Figures) -> Result<Vec<PathBuf>, BenchError> {
    let dir = &r.options.out;
    let panels_dir = dir.join("panels");
    std::fs::create_dir_all(&panels_dir).map_err(|e| BenchError::Output {
        path: panels_dir.clone(),
        message: e.to_string(),
    })?;
    let mut files = Vec::new();

    let plot_path = dir.join("error_vs_time.png");
    error_plot(r)
        .save(&plot_path)
        .map_err(png_error(&plot_path))?;
    files.push(plot_path);
    if r.options.depths.len() > 1 {
        let path = dir.join("error_vs_depth.png");
        depth_plot(r).save(&path).map_err(png_error(&path))?;
        files.push(path);
    }

    for (i, p, d) in panel_presses(r) {
        let reference = &fig.reference[i][p][d];
        let pos = r.positions[p];
        let panel = Panel {
            title: format!(
                "{} at ({:.1}, {:.1}) mm, depth {:.1} mm",
                r.indenters[i],
                pos[0] * 1e3,
                pos[1] * 1e3,
                r.options.depths[d] * 1e3
            ),
            width: fig.grid.width,
            height: fig.grid.height,
            fov: [fig.grid.fov_x, fig.grid.fov_y],
            reference: PanelImage {
                title: format!("reference (fine {:.2} mm)", r.options.reference_dx * 1e3),
                values: reference.depth.clone(),
            },
            modes: fig
                .modes
                .iter()
                .map(|(label, frames)| PanelImage {
                    title: label.clone(),
                    values: frames[i][p][d].depth.clone(),
                })
                .collect(),
        };
        let path = panels_dir.join(format!(
            "{}_p{}_d{:.1}mm.png",
            r.indenters[i],
            p,
            r.options.depths[d] * 1e3
        ));
        panel.save(&path).map_err(png_error(&path))?;
        files.push(path);
    }

    let csv_path = dir.join("results.csv");
    write_text(&csv_path, &csv(r))?;
    files.push(csv_path);
    let groups_path = dir.join("groups.csv");
    write_text(&groups_path, &groups_csv(r))?;
    files.push(groups_path);
    let md_path = dir.join("report.md");
    files.push(md_path.clone());
    let with_files = BenchResult {
        files: files.clone(),
        ..r.clone()
    };
    write_text(&md_path, &markdown(&with_files))?;
    Ok(files)
}
