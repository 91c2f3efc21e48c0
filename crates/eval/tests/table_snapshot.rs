//! Snapshots of Tables I/II (Markdown, LaTeX), the metrics table and the raw CSV for a small
//! hand-made result set; determinism and error cases of `eval::table`.
//! Update the snapshots with `UPDATE_EXPECT=1 cargo test -p eval --test table_snapshot`.

use eval::cell::{AttackModel, NoiseModel, UavModel};
use eval::methods::Method;
use eval::table::{
    ResultRow, TableError, TimingRow, metrics_markdown, read_results_csv, read_results_json, results_csv, results_json,
    streaming_markdown, table_latex, table_markdown, write_outputs,
};
use expect_test::expect;

fn run(model: UavModel, noise: NoiseModel, attack: AttackModel, method: Method, seed: u64, f1: f64) -> ResultRow {
    ResultRow {
        model,
        noise,
        attack,
        method,
        seed,
        precision: f1 + 0.01,
        recall: f1 - 0.01,
        f1,
        roc_auc: 0.9,
        pr_auc: 0.8,
        delay_median_s: if method == Method::Cusum { None } else { Some(0.5 + seed as f64 * 0.1) },
        delay_p90_s: if method == Method::Cusum { None } else { Some(1.5) },
        n_intervals: 4,
        n_missed: if method == Method::Cusum { 4 } else { 1 },
        false_alarms_per_min: 0.25,
        n_test_steps: 1000,
        stream_precision: (method == Method::QuadFormer).then_some(f1 - 0.09),
        stream_recall: (method == Method::QuadFormer).then_some(f1 - 0.11),
        stream_f1: (method == Method::QuadFormer).then_some(f1 - 0.1),
    }
}

fn timings(rows: &[ResultRow]) -> Vec<TimingRow> {
    rows.iter().map(|r| TimingRow::of(r, 1.0 + r.seed as f64, 0.1)).collect()
}

/// Model I: QUADFormer and CUSUM over two seeds in two columns, an extra method (the PX4 gate) in one column,
/// given out of order; Model II: one QUADFormer run.
fn sample() -> Vec<ResultRow> {
    use AttackModel as A;
    use NoiseModel as N;
    use UavModel as M;
    vec![
        run(M::I, N::Laplace, A::II, Method::QuadFormer, 2, 0.90),
        run(M::I, N::Exponential, A::I, Method::QuadFormer, 1, 0.92),
        run(M::I, N::Exponential, A::I, Method::QuadFormer, 2, 0.94),
        run(M::I, N::Laplace, A::II, Method::QuadFormer, 1, 0.88),
        run(M::I, N::Exponential, A::I, Method::Cusum, 1, 0.60),
        run(M::I, N::Exponential, A::I, Method::Cusum, 2, 0.64),
        run(M::I, N::Exponential, A::I, Method::Px4Gate, 1, 0.50),
        run(M::I, N::Exponential, A::I, Method::Px4Gate, 2, 0.52),
        run(M::II, N::Exponential, A::II, Method::QuadFormer, 1, 0.91),
    ]
}

#[test]
fn table1_markdown_snapshot() {
    let md = table_markdown(&sample(), UavModel::I).unwrap();
    expect![[r#"
        ## Table I: comparison results for Model I

        Per-step precision (P), recall (R) and F1 on the test flights, without point adjustment; mean ± sample standard deviation (n − 1) over 2 seeds.
        Columns: noise (Exp = exponential, Lap = Laplace) × attack (A-I = Attack I, sparse; A-II = Attack II, persistent).

        | Group | Method | Exp A-I P | Exp A-I R | Exp A-I F1 | Exp A-II P | Exp A-II R | Exp A-II F1 | Lap A-I P | Lap A-I R | Lap A-I F1 | Lap A-II P | Lap A-II R | Lap A-II F1 |
        |---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|
        | Traditional | CUSUM | 0.63 ± 0.03 | 0.61 ± 0.03 | 0.62 ± 0.03 | – | – | – | – | – | – | – | – | – |
        | Ours | QUADFormer | 0.94 ± 0.01 | 0.92 ± 0.01 | 0.93 ± 0.01 | – | – | – | – | – | – | 0.90 ± 0.01 | 0.88 ± 0.01 | 0.89 ± 0.01 |
        | Extra (not in the paper) | PX4 gate | 0.52 ± 0.01 | 0.50 ± 0.01 | 0.51 ± 0.01 | – | – | – | – | – | – | – | – | – |

        ### Paper's numbers (Table I of the paper), for comparison only

        Published values, copied from the paper; not produced by this code.

        | Group | Method | Exp A-I P | Exp A-I R | Exp A-I F1 | Exp A-II P | Exp A-II R | Exp A-II F1 | Lap A-I P | Lap A-I R | Lap A-I F1 | Lap A-II P | Lap A-II R | Lap A-II F1 |
        |---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|
        | Traditional | CUSUM | 0.69 | 0.64 | 0.66 | 0.71 | 0.59 | 0.64 | 0.70 | 0.62 | 0.66 | 0.71 | 0.58 | 0.64 |
        |  | SPRT | 0.69 | 0.67 | 0.69 | 0.68 | 0.68 | 0.67 | 0.69 | 0.67 | 0.68 | 0.68 | 0.67 | 0.67 |
        |  | BHT | 0.62 | 0.65 | 0.64 | 0.68 | 0.60 | 0.65 | 0.66 | 0.59 | 0.62 | 0.70 | 0.60 | 0.65 |
        | Learning-based | SVM | 0.88 | 0.82 | 0.85 | 0.75 | 0.69 | 0.72 | 0.88 | 0.82 | 0.85 | 0.75 | 0.69 | 0.72 |
        |  | CNN | 0.89 | 0.81 | 0.85 | 0.90 | 0.78 | 0.84 | 0.90 | 0.84 | 0.87 | 0.90 | 0.78 | 0.84 |
        |  | LSTM | 0.88 | 0.78 | 0.83 | 0.78 | 0.86 | 0.82 | 0.86 | 0.84 | 0.85 | 0.81 | 0.85 | 0.83 |
        | Ours | QUADFormer | 0.92 | 0.93 | 0.93 | 0.89 | 0.95 | 0.92 | 0.92 | 0.94 | 0.93 | 0.89 | 0.95 | 0.92 |
    "#]]
    .assert_eq(&md);
}

#[test]
fn table2_markdown_single_seed_has_no_spread() {
    let md = table_markdown(&sample(), UavModel::II).unwrap();
    let first_row = md.lines().find(|l| l.starts_with("| Ours | QUADFormer |")).unwrap();
    expect!["| Ours | QUADFormer | – | – | – | 0.92 | 0.90 | 0.91 | – | – | – | – | – | – |"].assert_eq(first_row);
}

#[test]
fn table1_latex_snapshot() {
    let tex = table_latex(&sample(), UavModel::I).unwrap();
    expect![[r#"
        % Table I, generated by eval::table from the run results; do not edit by hand.
        % Needs \usepackage{multirow} and \usepackage{tabularx}.
        \begin{table*}[h]
        \centering
        \caption{Comparison Results for Model I (this reproduction; per-step P, R, F1 without point adjustment, mean $\pm$ sample std over 2 seeds).}
        \label{tab:reproduced_model1}
        \bgroup
        \renewcommand{\arraystretch}{1.5}
        \scriptsize
        \begin{tabularx}{\textwidth}{|c|c|*{12}{>{\centering\arraybackslash}X|}}
        \hline
        \multirow{3}{*}{System Model} & UAV Model & \multicolumn{12}{c|}{Model I} \\
        \cline{2-14}
         & Noise Model & \multicolumn{6}{c|}{Exponential Noise} & \multicolumn{6}{c|}{Laplacian Noise} \\
        \cline{2-14}
         & Attack Model & \multicolumn{3}{c|}{Attack I} & \multicolumn{3}{c|}{Attack II} & \multicolumn{3}{c|}{Attack I} & \multicolumn{3}{c|}{Attack II} \\
        \hline
        Performance & Metric & P & R & F1 & P & R & F1 & P & R & F1 & P & R & F1 \\
        \hline
        \multirow{1}{*}{Traditional Method} & CUSUM & $0.63 \pm 0.03$ & $0.61 \pm 0.03$ & $0.62 \pm 0.03$ & -- & -- & -- & -- & -- & -- & -- & -- & -- \\
        \hline
        \multirow{1}{*}{\textbf{Ours}} & QUADFormer & $0.94 \pm 0.01$ & $0.92 \pm 0.01$ & $0.93 \pm 0.01$ & -- & -- & -- & -- & -- & -- & $0.90 \pm 0.01$ & $0.88 \pm 0.01$ & $0.89 \pm 0.01$ \\
        \hline
        \multirow{1}{*}{\parbox{2cm}{\centering Extra (not in\\ the paper)}} & PX4 gate & $0.52 \pm 0.01$ & $0.50 \pm 0.01$ & $0.51 \pm 0.01$ & -- & -- & -- & -- & -- & -- & -- & -- & -- \\
        \hline
        \end{tabularx}
        \egroup
        \end{table*}

        \begin{table*}[h]
        \centering
        \caption{Published numbers of the paper for Model I (its Table I), for comparison only.}
        \label{tab:paper_model1}
        \bgroup
        \renewcommand{\arraystretch}{1.5}
        \scriptsize
        \begin{tabularx}{\textwidth}{|c|c|*{12}{>{\centering\arraybackslash}X|}}
        \hline
        \multirow{3}{*}{System Model} & UAV Model & \multicolumn{12}{c|}{Model I} \\
        \cline{2-14}
         & Noise Model & \multicolumn{6}{c|}{Exponential Noise} & \multicolumn{6}{c|}{Laplacian Noise} \\
        \cline{2-14}
         & Attack Model & \multicolumn{3}{c|}{Attack I} & \multicolumn{3}{c|}{Attack II} & \multicolumn{3}{c|}{Attack I} & \multicolumn{3}{c|}{Attack II} \\
        \hline
        Performance & Metric & P & R & F1 & P & R & F1 & P & R & F1 & P & R & F1 \\
        \hline
        \multirow{3}{*}{Traditional Method} & CUSUM & 0.69 & 0.64 & 0.66 & 0.71 & 0.59 & 0.64 & 0.70 & 0.62 & 0.66 & 0.71 & 0.58 & 0.64 \\
        \cline{2-14}
         & SPRT & 0.69 & 0.67 & 0.69 & 0.68 & 0.68 & 0.67 & 0.69 & 0.67 & 0.68 & 0.68 & 0.67 & 0.67 \\
        \cline{2-14}
         & BHT & 0.62 & 0.65 & 0.64 & 0.68 & 0.60 & 0.65 & 0.66 & 0.59 & 0.62 & 0.70 & 0.60 & 0.65 \\
        \hline
        \multirow{3}{*}{\parbox{2cm}{\centering Learning-based\\ Method}} & SVM & 0.88 & 0.82 & 0.85 & 0.75 & 0.69 & 0.72 & 0.88 & 0.82 & 0.85 & 0.75 & 0.69 & 0.72 \\
        \cline{2-14}
         & CNN & 0.89 & 0.81 & 0.85 & 0.90 & 0.78 & 0.84 & 0.90 & 0.84 & 0.87 & 0.90 & 0.78 & 0.84 \\
        \cline{2-14}
         & LSTM & 0.88 & 0.78 & 0.83 & 0.78 & 0.86 & 0.82 & 0.86 & 0.84 & 0.85 & 0.81 & 0.85 & 0.83 \\
        \hline
        \multirow{1}{*}{\textbf{Ours}} & QUADFormer & 0.92 & 0.93 & 0.93 & 0.89 & 0.95 & 0.92 & 0.92 & 0.94 & 0.93 & 0.89 & 0.95 & 0.92 \\
        \hline
        \end{tabularx}
        \egroup
        \end{table*}
    "#]]
    .assert_eq(&tex);
}

#[test]
fn metrics_and_csv_snapshot() {
    expect![[r#"
        | Cell | Method | ROC AUC | PR AUC | Delay median (s) | Delay p90 (s) | Missed / intervals | False alarms / min |
        |---|---|---:|---:|---:|---:|---:|---:|
        | Model I, exponential noise, Attack I | CUSUM | 0.90 ± 0.00 | 0.80 ± 0.00 | – | – | 8 / 8 | 0.25 ± 0.00 |
        | Model I, exponential noise, Attack I | QUADFormer | 0.90 ± 0.00 | 0.80 ± 0.00 | 0.65 ± 0.07 | 1.50 ± 0.00 | 2 / 8 | 0.25 ± 0.00 |
        | Model I, exponential noise, Attack I | PX4 gate | 0.90 ± 0.00 | 0.80 ± 0.00 | 0.65 ± 0.07 | 1.50 ± 0.00 | 2 / 8 | 0.25 ± 0.00 |
        | Model I, laplace noise, Attack II | QUADFormer | 0.90 ± 0.00 | 0.80 ± 0.00 | 0.65 ± 0.07 | 1.50 ± 0.00 | 2 / 8 | 0.25 ± 0.00 |
        | Model II, exponential noise, Attack II | QUADFormer | 0.90 | 0.80 | 0.60 | 1.50 | 1 / 4 | 0.25 |
    "#]]
    .assert_eq(&metrics_markdown(&sample()).unwrap());
    expect![[r#"
        ## Streaming against offline F1 of the learning methods

        Per-step F1 on the test flights, offline / streaming, mean ± sample standard deviation over seeds. Offline is the figure of Tables I and II; streaming scores every step as the newest of its window (causal, what `OnlineDetector` and `quadformer fuse` use), at a threshold chosen on the validation split's streaming scores.

        | Model | Method | Exp A-I | Exp A-II | Lap A-I | Lap A-II |
        |---|---|---|---|---|---|
        | I | QUADFormer | 0.93 ± 0.01 / 0.83 ± 0.01 | – | – | 0.89 ± 0.01 / 0.79 ± 0.01 |
        | II | QUADFormer | – | 0.91 / 0.81 | – | – |
    "#]].assert_eq(&streaming_markdown(&sample()).unwrap());
    expect![[r#"
        model,noise,attack,method,seed,precision,recall,f1,roc_auc,pr_auc,delay_median_s,delay_p90_s,n_intervals,n_missed,false_alarms_per_min,n_test_steps,stream_precision,stream_recall,stream_f1
        I,exponential,I,CUSUM,1,0.61,0.59,0.6,0.9,0.8,,,4,4,0.25,1000,,,
        I,exponential,I,CUSUM,2,0.65,0.63,0.64,0.9,0.8,,,4,4,0.25,1000,,,
        I,exponential,I,QUADFormer,1,0.93,0.91,0.92,0.9,0.8,0.6,1.5,4,1,0.25,1000,0.8300000000000001,0.81,0.8200000000000001
        I,exponential,I,QUADFormer,2,0.95,0.9299999999999999,0.94,0.9,0.8,0.7,1.5,4,1,0.25,1000,0.85,0.83,0.84
        I,exponential,I,PX4 gate,1,0.51,0.49,0.5,0.9,0.8,0.6,1.5,4,1,0.25,1000,,,
        I,exponential,I,PX4 gate,2,0.53,0.51,0.52,0.9,0.8,0.7,1.5,4,1,0.25,1000,,,
        I,laplace,II,QUADFormer,1,0.89,0.87,0.88,0.9,0.8,0.6,1.5,4,1,0.25,1000,0.79,0.77,0.78
        I,laplace,II,QUADFormer,2,0.91,0.89,0.9,0.9,0.8,0.7,1.5,4,1,0.25,1000,0.81,0.79,0.8
        II,exponential,II,QUADFormer,1,0.92,0.9,0.91,0.9,0.8,0.6,1.5,4,1,0.25,1000,0.8200000000000001,0.8,0.81
    "#]]
    .assert_eq(&results_csv(&sample()).unwrap());
}

#[test]
fn outputs_are_deterministic_and_round_trip() -> Result<(), Box<dyn std::error::Error>> {
    let dir = tempfile::tempdir()?;
    let mut shuffled = sample();
    shuffled.reverse();
    let a = write_outputs(&dir.path().join("a"), &sample(), &timings(&sample()))?;
    let b = write_outputs(&dir.path().join("b"), &shuffled, &timings(&shuffled))?;
    for (pa, pb) in a.iter().zip(&b) {
        assert_eq!(std::fs::read(pa)?, std::fs::read(pb)?, "{} differs", pa.display());
    }
    // Timings never enter the deterministic files.
    assert!(!std::fs::read_to_string(dir.path().join("a/results.csv"))?.contains("train_s"));
    let json = read_results_json(&dir.path().join("a/results.json"))?;
    assert_eq!(json.results.len(), 9);
    let csv = read_results_csv(&dir.path().join("a/results.csv"))?;
    assert_eq!(csv, json.results);
    assert_eq!(results_json(&sample())?, std::fs::read_to_string(dir.path().join("a/results.json"))?);
    Ok(())
}

#[test]
fn bad_results_are_rejected() {
    let mut rs = sample();
    rs.push(rs[0].clone());
    assert!(matches!(results_csv(&rs), Err(TableError::Duplicate { seed: 2, .. })));
    let mut rs = sample();
    rs[0].f1 = f64::NAN;
    let err = table_markdown(&rs, UavModel::I).unwrap_err();
    assert!(matches!(err, TableError::Value { field: "f1", .. }));
    assert_eq!(
        err.to_string(),
        "Model I, laplace noise, Attack II / QUADFormer / seed 2: field `f1` = NaN is out of range"
    );
}

#[test]
fn newer_json_version_is_a_clear_error() -> Result<(), Box<dyn std::error::Error>> {
    let dir = tempfile::tempdir()?;
    let path = dir.path().join("results.json");
    std::fs::write(&path, r#"{"format_version": 99, "results": []}"#)?;
    assert!(matches!(read_results_json(&path), Err(TableError::Version { got: 99, .. })));
    Ok(())
}
