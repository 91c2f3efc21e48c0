//! The tidy checks, run by `cargo xtask tidy` and, as a `#[test]`, by `cargo test --workspace`:
//!
//! 1. layering: a workspace crate may depend (normal, build or dev) only on crates above it in
//!    the layering of docs/ARCHITECTURE.md ([`LAYERS`], the order of its Code Map); a member
//!    missing from [`LAYERS`] is an error too;
//! 2. candle must not be reachable, transitively and with all features on, from the crates in
//!    [`NO_CANDLE`]; the error shows the dependency path;
//! 3. every `.rs` file under `crates/` and `xtask/` starts with a `//!` doc comment;
//! 4. `docs/ARCHITECTURE.md` has a `### crates/<name>` Code Map heading for every crate (and
//!    `### xtask`), and its `## Paper Map` section names every paper label (`eq:…`, `alg:…`)
//!    that a code comment cites.
//!
//! Every problem is collected and reported together, each on its own line with the file or
//! crate concerned.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::fs;
use std::path::{Path, PathBuf};

use anyhow::{Context as _, bail};
use cargo_metadata::{CargoOpt, DependencyKind, Metadata, MetadataCommand, PackageId};

use crate::project_root;

/// The layers of docs/ARCHITECTURE.md (the order of its Code Map), top (lowest) first: a crate
/// may depend only on crates listed before it.
pub(crate) const LAYERS: [&str; 10] = [
    "detection-metrics",
    "uav-dynamics",
    "ekf-residue",
    "attack-inject",
    "nn-toolkit",
    "quadformer-model",
    "baselines",
    "resilient-fusion",
    "eval",
    "xtask",
];

/// Crates from which no `candle-*` crate may be reachable (docs/ARCHITECTURE.md, "Code Map").
pub(crate) const NO_CANDLE: [&str; 5] =
    ["detection-metrics", "uav-dynamics", "ekf-residue", "attack-inject", "resilient-fusion"];

/// Runs every check on the workspace; fails with the list of problems.
pub(crate) fn run() -> anyhow::Result<()> {
    let root = project_root();
    let metadata = MetadataCommand::new()
        .manifest_path(root.join("Cargo.toml"))
        .features(CargoOpt::AllFeatures)
        .exec()
        .context("cannot run `cargo metadata`")?;
    let mut problems = Vec::new();
    problems.extend(check_layering(&metadata));
    problems.extend(check_candle(&metadata));
    let rs_files = rust_files(&root)?;
    problems.extend(check_file_docs(&root, &rs_files)?);
    let members: Vec<(String, bool)> = metadata
        .workspace_packages()
        .iter()
        .map(|p| (p.name.to_string(), p.manifest_path.as_std_path().starts_with(root.join("crates"))))
        .collect();
    let mut cited = BTreeMap::new();
    for f in &rs_files {
        let text = fs::read_to_string(f).with_context(|| format!("cannot read {}", f.display()))?;
        for label in comment_labels(&text) {
            cited.entry(label).or_insert_with(|| relative(&root, f));
        }
    }
    let arch = root.join("docs/ARCHITECTURE.md");
    match fs::read_to_string(&arch) {
        Ok(doc) => problems.extend(check_architecture(&doc, &members, &cited)),
        Err(_) => problems.push(format!(
            "docs/ARCHITECTURE.md is missing: it needs a Code Map heading for each of [{}] and a `## Paper Map` \
             naming [{}]",
            members.iter().map(|(n, _)| n.as_str()).collect::<Vec<_>>().join(", "),
            cited.keys().cloned().collect::<Vec<_>>().join(", ")
        )),
    }
    if problems.is_empty() {
        eprintln!("tidy: ok ({} crates, {} Rust files, {} cited labels)", members.len(), rs_files.len(), cited.len());
        Ok(())
    } else {
        bail!("tidy found {} problem(s):\n  - {}", problems.len(), problems.join("\n  - "))
    }
}

fn relative(root: &Path, path: &Path) -> String {
    path.strip_prefix(root).unwrap_or(path).display().to_string()
}

/// Layer index of a workspace crate, if it is in the table.
fn layer(name: &str) -> Option<usize> {
    LAYERS.iter().position(|l| *l == name)
}

/// Rule 1: internal dependencies point only upwards in [`LAYERS`].
fn check_layering(metadata: &Metadata) -> Vec<String> {
    let members: BTreeSet<String> = metadata.workspace_packages().iter().map(|p| p.name.to_string()).collect();
    let edges = metadata.workspace_packages().into_iter().flat_map(|p| {
        p.dependencies
            .iter()
            .filter(|d| members.contains(&d.name))
            .map(|d| (p.name.to_string(), d.name.clone(), format!("{:?}", d.kind).to_lowercase()))
            .collect::<Vec<_>>()
    });
    layering_problems(&members, edges)
}

/// The layering problems of a dependency list `(from, to, kind)` between `members`.
fn layering_problems(
    members: &BTreeSet<String>,
    edges: impl IntoIterator<Item = (String, String, String)>,
) -> Vec<String> {
    let mut problems: Vec<String> = members
        .iter()
        .filter(|m| layer(m).is_none())
        .map(|m| format!("crate `{m}` is not in the docs/ARCHITECTURE.md layering table (xtask/src/tidy.rs LAYERS)"))
        .collect();
    for (from, to, kind) in edges {
        if let (Some(lf), Some(lt)) = (layer(&from), layer(&to))
            && lt >= lf
        {
            problems.push(format!(
                "crate `{from}` has a {kind} dependency on `{to}`, which is not above it in the docs/ARCHITECTURE.md layering \
                 ({})",
                LAYERS.join(" → ")
            ));
        }
    }
    problems
}

/// Rule 2: no `candle-*` package reachable from the [`NO_CANDLE`] crates.
fn check_candle(metadata: &Metadata) -> Vec<String> {
    let Some(resolve) = &metadata.resolve else {
        return vec!["`cargo metadata` returned no dependency graph".to_owned()];
    };
    let name_of: BTreeMap<&PackageId, String> = metadata.packages.iter().map(|p| (&p.id, p.name.to_string())).collect();
    // Edges: the root's own dev-dependencies count, transitive ones follow normal and build only.
    let mut graph: BTreeMap<&PackageId, Vec<(&PackageId, bool)>> = BTreeMap::new();
    for node in &resolve.nodes {
        let deps = node
            .deps
            .iter()
            .map(|d| {
                let non_dev =
                    d.dep_kinds.is_empty() || d.dep_kinds.iter().any(|k| k.kind != DependencyKind::Development);
                (&d.pkg, non_dev)
            })
            .collect();
        graph.insert(&node.id, deps);
    }
    let mut problems = Vec::new();
    for pkg in metadata.workspace_packages() {
        if !NO_CANDLE.contains(&pkg.name.as_str()) {
            continue;
        }
        if let Some(path) = path_to(&pkg.id, &graph, |id| name_of.get(id).is_some_and(|n| is_candle(n))) {
            let shown: Vec<&str> = path.iter().map(|id| name_of.get(id).map_or("?", String::as_str)).collect();
            problems.push(format!("candle is reachable from `{}`: {}", pkg.name, shown.join(" → ")));
        }
    }
    problems
}

fn is_candle(name: &str) -> bool {
    name == "candle" || name.starts_with("candle-") || name.starts_with("candle_")
}

/// Breadth-first search from `root` for a node satisfying `target`; every edge of the root
/// counts, deeper only non-dev edges. Returns the path, root first.
fn path_to<'a>(
    root: &'a PackageId,
    graph: &BTreeMap<&'a PackageId, Vec<(&'a PackageId, bool)>>,
    target: impl Fn(&PackageId) -> bool,
) -> Option<Vec<&'a PackageId>> {
    let mut parent: BTreeMap<&PackageId, &PackageId> = BTreeMap::new();
    let mut queue = VecDeque::from([root]);
    let mut seen = BTreeSet::from([root]);
    while let Some(id) = queue.pop_front() {
        for &(dep, non_dev) in graph.get(id).map_or(&[][..], Vec::as_slice) {
            if (!non_dev && id != root) || !seen.insert(dep) {
                continue;
            }
            parent.insert(dep, id);
            if target(dep) {
                let mut path = vec![dep];
                let mut cur = dep;
                while let Some(&p) = parent.get(cur) {
                    path.push(p);
                    cur = p;
                }
                path.reverse();
                return Some(path);
            }
            queue.push_back(dep);
        }
    }
    None
}

/// Every `.rs` file under `crates/` and `xtask/`, skipping `target` and hidden directories.
fn rust_files(root: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    let mut stack = vec![root.join("crates"), root.join("xtask")];
    while let Some(dir) = stack.pop() {
        if !dir.is_dir() {
            continue;
        }
        for entry in fs::read_dir(&dir).with_context(|| format!("cannot list {}", dir.display()))? {
            let path = entry?.path();
            let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            if path.is_dir() {
                if name != "target" && !name.starts_with('.') {
                    stack.push(path);
                }
            } else if name.ends_with(".rs") {
                out.push(path);
            }
        }
    }
    out.sort();
    Ok(out)
}

/// Rule 3: the first non-blank line of every file is a `//!` comment.
fn check_file_docs(root: &Path, files: &[PathBuf]) -> anyhow::Result<Vec<String>> {
    let mut problems = Vec::new();
    for f in files {
        let text = fs::read_to_string(f).with_context(|| format!("cannot read {}", f.display()))?;
        if !starts_with_module_doc(&text) {
            problems.push(format!("{}: the file must start with a `//!` doc comment", relative(root, f)));
        }
    }
    Ok(problems)
}

fn starts_with_module_doc(text: &str) -> bool {
    text.lines().find(|l| !l.trim().is_empty()).is_some_and(|l| l.trim_start().starts_with("//!"))
}

/// Paper labels (`eq:…`, `alg:…`) in `text`: a prefix not preceded by an identifier character,
/// followed by at least one of `[A-Za-z0-9_]`.
fn labels_in(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let bytes = text.as_bytes();
    for prefix in ["eq:", "alg:"] {
        let mut from = 0;
        while let Some(pos) = text[from..].find(prefix) {
            let start = from + pos;
            from = start + prefix.len();
            if start > 0 && (bytes[start - 1].is_ascii_alphanumeric() || bytes[start - 1] == b'_') {
                continue;
            }
            let len = bytes[from..].iter().take_while(|b| b.is_ascii_alphanumeric() || **b == b'_').count();
            if len > 0 {
                out.push(text[start..from + len].to_owned());
            }
        }
    }
    out
}

/// Paper labels cited in the comments (`//`, `///`, `//!`) of a Rust source.
fn comment_labels(src: &str) -> BTreeSet<String> {
    src.lines().filter_map(|l| l.find("//").map(|i| &l[i..])).flat_map(labels_in).collect()
}

/// Normalised level-3 headings of a Markdown text: the first word, without backticks or a
/// trailing slash (`### \`crates/eval\`/ (top)` → `crates/eval`).
fn level3_headings(doc: &str) -> BTreeSet<String> {
    doc.lines()
        .filter_map(|l| l.trim_start().strip_prefix("### "))
        .filter_map(|h| h.split_whitespace().next())
        .map(|w| w.replace('`', "").trim_end_matches('/').to_owned())
        .collect()
}

/// Labels in the `## Paper Map` section (up to the next level-1 or level-2 heading).
fn paper_map_labels(doc: &str) -> Option<BTreeSet<String>> {
    let mut in_section = false;
    let mut found = false;
    let mut out = BTreeSet::new();
    for line in doc.lines() {
        let t = line.trim_start();
        let level2 = t.starts_with("## ") || t.starts_with("# ");
        if level2 {
            in_section = t.trim_start_matches('#').trim().to_lowercase().starts_with("paper map");
            found |= in_section;
            continue;
        }
        if in_section {
            out.extend(labels_in(line));
        }
    }
    found.then_some(out)
}

/// Rule 4: Code Map headings and Paper Map coverage. `members` are `(name, under_crates_dir)`;
/// `cited` maps each label to a file that cites it.
fn check_architecture(doc: &str, members: &[(String, bool)], cited: &BTreeMap<String, String>) -> Vec<String> {
    let mut problems = Vec::new();
    let headings = level3_headings(doc);
    for (name, under_crates) in members {
        let want = if *under_crates { format!("crates/{name}") } else { name.clone() };
        if !headings.contains(&want) {
            problems.push(format!("docs/ARCHITECTURE.md: Code Map lacks a `### {want}` section"));
        }
    }
    match paper_map_labels(doc) {
        None => problems.push(format!(
            "docs/ARCHITECTURE.md: no `## Paper Map` section; code cites [{}]",
            cited.keys().cloned().collect::<Vec<_>>().join(", ")
        )),
        Some(mapped) => {
            for (label, file) in cited {
                if !mapped.contains(label) {
                    problems.push(format!("docs/ARCHITECTURE.md: Paper Map lacks `{label}` (cited in {file})"));
                }
            }
        }
    }
    problems
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The whole workspace is tidy (`cargo test --workspace` runs this).
    #[test]
    fn tidy() {
        if let Err(e) = run() {
            panic!("{e:#}");
        }
    }

    #[test]
    fn layering_flags_downward_and_unknown_crates() {
        let members: BTreeSet<String> =
            ["uav-dynamics", "ekf-residue", "eval", "mystery"].into_iter().map(String::from).collect();
        let edge = |a: &str, b: &str| (a.to_owned(), b.to_owned(), "normal".to_owned());
        let p = layering_problems(&members, [edge("ekf-residue", "uav-dynamics"), edge("eval", "ekf-residue")]);
        assert_eq!(p.len(), 1, "{p:?}");
        assert!(p[0].contains("mystery"));
        let p = layering_problems(&members, [edge("uav-dynamics", "ekf-residue"), edge("eval", "eval")]);
        assert_eq!(p.len(), 3, "{p:?}");
        assert!(p[1].contains("`uav-dynamics` has a normal dependency on `ekf-residue`"));
    }

    #[test]
    fn labels_are_found_in_comments_only() {
        // Built from pieces so that this file cites no label itself.
        let e = "eq";
        let src = format!(
            "let x = \"{e}:not_a_comment\";\n/// Implements {e}:model1f and alg:alg1.\nfoo(); // see ({e}:ekf_update)\nfreq:bar // req:x"
        );
        let got: Vec<String> = comment_labels(&src).into_iter().collect();
        assert_eq!(got, ["alg:alg1", "eq:ekf_update", "eq:model1f"]);
        assert!(labels_in("eq: alone").is_empty());
    }

    #[test]
    fn candle_path_skips_transitive_dev_edges() {
        let id = |s: &str| PackageId { repr: s.to_owned() };
        let (root, mid, dev_only, candle) = (id("root"), id("mid"), id("devtool"), id("candle-core"));
        let mut graph: BTreeMap<&PackageId, Vec<(&PackageId, bool)>> = BTreeMap::new();
        graph.insert(&root, vec![(&mid, true)]);
        graph.insert(&mid, vec![(&dev_only, false)]);
        graph.insert(&dev_only, vec![(&candle, true)]);
        let is_candle_id = |p: &PackageId| is_candle(&p.repr);
        assert_eq!(path_to(&root, &graph, is_candle_id), None);
        graph.insert(&mid, vec![(&dev_only, true)]);
        let path = path_to(&root, &graph, is_candle_id).unwrap();
        assert_eq!(path.iter().map(|p| p.repr.as_str()).collect::<Vec<_>>(), ["root", "mid", "devtool", "candle-core"]);
    }

    #[test]
    fn module_docs_are_detected() {
        assert!(starts_with_module_doc("\n//! Doc.\nfn f() {}"));
        assert!(!starts_with_module_doc("// Not a doc.\n//! Late."));
        assert!(!starts_with_module_doc(""));
    }

    #[test]
    fn architecture_doc_is_parsed_robustly() {
        let e = "eq";
        let doc = format!(
            "# Architecture\n## Code Map\n### `crates/uav-dynamics`\ntext\n###  crates/eval/ (top)\n### xtask\n\
             ## Paper Map\n| label | where |\n|---|---|\n| `{e}:model1f`, `alg:alg1` | x |\n## Cross-Cutting Concerns\n\
             mentions {e}:late\n"
        );
        let members = vec![
            ("uav-dynamics".to_owned(), true),
            ("eval".to_owned(), true),
            ("baselines".to_owned(), true),
            ("xtask".to_owned(), false),
        ];
        let cited: BTreeMap<String, String> =
            [(format!("{e}:model1f"), "a.rs".to_owned()), (format!("{e}:late"), "b.rs".to_owned())]
                .into_iter()
                .collect();
        let p = check_architecture(&doc, &members, &cited);
        assert_eq!(p.len(), 2, "{p:?}");
        assert!(p[0].contains("`### crates/baselines`"));
        assert!(p[1].contains(&format!("`{e}:late` (cited in b.rs)")));
        let p = check_architecture("# Architecture\n", &members, &cited);
        assert!(p.iter().any(|m| m.contains("no `## Paper Map` section")), "{p:?}");
    }
}
