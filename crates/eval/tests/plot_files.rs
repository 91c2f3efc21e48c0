//! Every figure of `eval::plot` is written as a non-empty PNG and SVG, atomically (no
//! temporary file left behind), with its text rendered by the embedded font; bad input is a
//! `PlotError::Data`.

use eval::metrics::{MeanStd, RocCurve};
use eval::plot::{
    PlotError, StatisticTrace, SweepSeries, TopView, f1_amplitude_plot, roc_plot, statistic_plot, top_view_plot,
};

type TestResult = Result<(), Box<dyn std::error::Error>>;

/// Checks both files exist, are non-empty, PNG has its magic number, SVG holds `needle`, and
/// nothing else (no temporary) is in the directory besides `expected_files`.
fn check(paths: &[std::path::PathBuf], needle: &str) -> TestResult {
    assert_eq!(paths.len(), 2);
    let png = std::fs::read(&paths[0])?;
    assert!(png.len() > 1000, "{} is {} bytes", paths[0].display(), png.len());
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    let svg = std::fs::read_to_string(&paths[1])?;
    assert!(svg.starts_with("<svg"), "{}", &svg[..40.min(svg.len())]);
    assert!(svg.contains(needle), "SVG lacks {needle:?}");
    Ok(())
}

fn no_temporaries(dir: &std::path::Path) -> TestResult {
    for e in std::fs::read_dir(dir)? {
        let name = e?.file_name().to_string_lossy().into_owned();
        assert!(!name.starts_with('.'), "temporary left behind: {name}");
    }
    Ok(())
}

#[test]
fn roc_plot_files() -> TestResult {
    let dir = tempfile::tempdir()?;
    let scores: Vec<f64> = (0..200).map(|k| f64::from(k % 17) + if k % 5 == 0 { 8.0 } else { 0.0 }).collect();
    let labels: Vec<bool> = (0..200).map(|k| k % 5 == 0).collect();
    let good = RocCurve::new([(&scores[..], &labels[..])])?;
    let flat = RocCurve::new([(&[1.0, 1.0][..], &[true, false][..])])?;
    let paths = roc_plot(
        &dir.path().join("roc_m1-exponential-a1"),
        "Model I, exponential, Attack I",
        &[("QUADFormer", &good), ("CUSUM", &flat)],
    )?;
    check(&paths, "QUADFormer (AUC")?;
    assert!(matches!(roc_plot(&dir.path().join("x"), "t", &[]), Err(PlotError::Data { .. })));
    no_temporaries(dir.path())
}

#[test]
fn f1_sweep_files() -> TestResult {
    let dir = tempfile::tempdir()?;
    let pts: Vec<(f64, MeanStd)> =
        [0.5, 1.0, 2.0, 5.0, 10.0].iter().map(|&a| (a, MeanStd::new("f1", &[a / 11.0, a / 10.0]).unwrap())).collect();
    let one: Vec<(f64, MeanStd)> =
        vec![(0.5, MeanStd::new("f1", &[0.1]).unwrap()), (10.0, MeanStd::new("f1", &[0.9]).unwrap())];
    let series = [SweepSeries { label: "QUADFormer", points: &pts }, SweepSeries { label: "Chi2", points: &one }];
    let paths =
        f1_amplitude_plot(&dir.path().join("f1_sweep"), "F1 vs amplitude", "Attack amplitude (GPS σ)", &series)?;
    check(&paths, "Chi2")?;
    no_temporaries(dir.path())
}

#[test]
fn statistic_plot_files() -> TestResult {
    let dir = tempfile::tempdir()?;
    let t: Vec<f64> = (0..300).map(|k| f64::from(k) * 0.1).collect();
    let g: Vec<f64> = t.iter().map(|&t| if (10.0..20.0).contains(&t) { (t - 10.0) * 2.0 } else { 0.3 }).collect();
    let alarms: Vec<bool> = g.iter().map(|&v| v > 5.0).collect();
    let trace =
        StatisticTrace { t: &t, statistic: &g, threshold: 5.0, attacks: &[(10.0, 20.0)], alarms: Some(&alarms) };
    let paths = statistic_plot(&dir.path().join("cusum"), "CUSUM after an attack", "CUSUM g_k", trace)?;
    check(&paths, "attack interval")?;
    let bad = StatisticTrace { t: &t[..3], statistic: &g, threshold: 1.0, attacks: &[], alarms: None };
    assert!(matches!(statistic_plot(&dir.path().join("bad"), "t", "y", bad), Err(PlotError::Data { .. })));
    no_temporaries(dir.path())
}

#[test]
fn top_view_files() -> TestResult {
    let dir = tempfile::tempdir()?;
    let reference: Vec<(f64, f64)> =
        (0..100).map(|k| (f64::from(k).cos() * 10.0, (f64::from(k) * 2.0).sin() * 5.0)).collect();
    let truth: Vec<(f64, f64)> = reference.iter().map(|(x, y)| (x + 0.1, y - 0.1)).collect();
    let estimate: Vec<(f64, f64)> =
        truth.iter().enumerate().map(|(k, (x, y))| (x + if k > 50 { 1.0 } else { 0.0 }, *y)).collect();
    let attacked: Vec<bool> = (0..100).map(|k| (50..70).contains(&k)).collect();
    let view = TopView { reference: &reference, truth: &truth, estimate: &estimate, attacked: &attacked };
    let paths = top_view_plot(&dir.path().join("sub/flight"), "Eight-shape flight", view)?;
    check(&paths, "estimate under attack")?;
    let bad = TopView { attacked: &attacked[..10], ..view };
    assert!(matches!(top_view_plot(&dir.path().join("bad"), "t", bad), Err(PlotError::Data { .. })));
    no_temporaries(&dir.path().join("sub"))
}
