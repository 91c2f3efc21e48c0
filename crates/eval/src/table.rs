//! Tables I and II in the paper's layout (Markdown, LaTeX) and raw results (CSV, JSON).
