"""The paper's experiments on the world: Tables 1-5 and Figures 3, 5 and 6, each one function
that trains what it needs, evaluates on the world's TVL-style test split with the offline judge,
and returns a `Report` (markdown table + plotly figure + data); `run_all` writes them all into
one markdown report (`docs/results.md`).

Every generator variant starts from the same stage-1 generator (the shipped RA-Touch
checkpoint's prompt projection and decoder base, i.e. the TVL-LLaMA stage) and gets the same
stage-2 budget (`ExperimentConfig.steps` LoRA steps, the same batches): the baseline trains LoRA
alone, the RA-Touch variants train LoRA plus an integrator over the neighbours their retrieval
setting finds. So rows differ only by what the experiment varies. Variant results are cached on
disk (`cache_dir()/experiments/`), keyed by everything they depend on (settings, weights, corpus
and the source of the code that trains them), so that `run_all` reuses what a single experiment
command computed.

Modules: `variants` (`Variant`, `ExperimentConfig`, `Report`), `lab` (`Lab`: shared state,
training, judging, the disk cache), `compare` (rows, tables and charts against the baseline),
`tables` (Tables 1-6), `figures` (Figures 3, 5, 6) and `results` (`EXPERIMENTS`, running them,
the report files and docs/results.md).
"""

from ratouch.eval.experiments.compare import JUDGE_COLS, diff_chart, paired_difference
from ratouch.eval.experiments.figures import fig3_corpus_size, fig5_loss_pca, fig6_top_k
from ratouch.eval.experiments.lab import TRAINING_CODE, Lab, make_integrator, source_sha256
from ratouch.eval.experiments.results import (
    EXPERIMENTS,
    companion_sections,
    results_markdown,
    run_experiments,
    write_report,
)
from ratouch.eval.experiments.tables import (
    table1_main,
    table2_ablation,
    table3_caption_type,
    table4_query_key,
    table5_integration,
    table6_withheld,
)
from ratouch.eval.experiments.variants import (
    BASELINE,
    CAPTION_TYPES,
    INTEGRATIONS,
    QUERY_KEY,
    RA_TOUCH,
    SUBSET_NAMES,
    ExperimentConfig,
    Report,
    Variant,
)

_diff_chart = diff_chart  # its name before the split into modules

__all__ = [
    "BASELINE", "CAPTION_TYPES", "EXPERIMENTS", "INTEGRATIONS", "JUDGE_COLS", "QUERY_KEY",
    "RA_TOUCH", "SUBSET_NAMES", "TRAINING_CODE", "ExperimentConfig", "Lab", "Report", "Variant",
    "companion_sections", "diff_chart", "fig3_corpus_size", "fig5_loss_pca", "fig6_top_k",
    "make_integrator", "paired_difference", "results_markdown", "run_experiments",
    "source_sha256", "table1_main", "table2_ablation", "table3_caption_type",
    "table4_query_key", "table5_integration", "table6_withheld", "write_report",
]
