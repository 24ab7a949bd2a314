"""The evaluation judges of the TVL benchmark protocol: an offline judge and an LLM judge.

TVL scores a generated tactile description by asking GPT-4 to rate it against the ground-truth
adjectives on a 1-10 scale (`JUDGE_PROMPT` is written in the spirit of TVL's prompt).

`OfflineJudge` needs no network. It splits label and answer into adjectives, compares them with
hand-made synonym groups and antonym pairs (soft ~ plush ~ cushioned; soft vs hard; ...) and
weighs every answer word by its informativeness: words that fit nearly every label (label base
rates from the fit data) or that the judged system says for nearly every sample (its own word
rates, measured at judge time on the answers being judged) earn little; antonym clashes cost.
Five weighted features map to 1-10 with ``1 + 9 * sigmoid(b + w . z)``, fitted by least squares
on the FIT half of the published TVL judge data (`fit_offline_judge`, stored in
``ratouch/configs/judge/offline.json``). `validate_judge` measures it on held-out samples, on a
held-out system (leave one out) and under style shifts; docs/judge.md has the figures.
`mean_ci` / `score_stats` give the 95 % bootstrap CI, adjective F1 and mean length that every
system comparison prints.

`LLMJudge` asks any OpenAI-compatible chat-completions endpoint, retries a bounded number of
times, and falls back to the offline judge when the endpoint fails or answers without a score.

The package, by concept (its public names are re-exported here: import them from
`ratouch.eval.judge`):
``records`` (the 1-10 range, TVL result files, GPT-4's score), ``lexicon`` (synonyms,
antonyms), ``features`` (word rates, informativeness, the judge's features), ``offline``
(`OfflineJudge` and its stored calibration), ``llm`` (`LLMJudge`), ``stats`` (bootstrap CIs,
`score_stats`, `judge_results`), ``calibration`` (the TVL judge data, its split, the fit),
``shifts`` (style shifts, length effect), ``validation`` (`validate_judge`, leave one system
out), ``explain`` (word-by-word explanations, offline vs LLM agreement).
"""

from __future__ import annotations

from ratouch.eval.judge.calibration import (
    DATA_DIR_ENV,
    MODELS,
    fit_calibration,
    fit_offline_judge,
    heldout_split,
    judge_data_dir,
    load_tvl_results,
)
from ratouch.eval.judge.explain import (
    compare_judges,
    explain_results,
    format_compare,
    format_explain,
)
from ratouch.eval.judge.features import (
    FEATURES,
    IGNORE_BELOW,
    NO_RATES,
    PSEUDO_ANSWERS,
    WordRates,
    answer_rates,
    informativeness,
    judge_features,
    label_fit_rates,
    word_table,
)
from ratouch.eval.judge.lexicon import (
    ANTONYM_GROUPS,
    NON_TACTILE,
    SYNONYM,
    antonymy,
    similarity,
)
from ratouch.eval.judge.llm import (
    JUDGE_PROMPT,
    JUDGE_SYSTEM,
    LLMJudge,
    LLMJudgeConfig,
    build_judge_prompt,
)
from ratouch.eval.judge.offline import (
    CONFIG_PATH,
    OfflineJudge,
    load_offline_config,
    write_offline_config,
)
from ratouch.eval.judge.records import (
    EVAL_KEY,
    LABEL_KEY,
    MAX_SCORE,
    MIN_SCORE,
    RESPONSE_KEY,
    SUBSETS,
    check_records,
    parse_gpt_score,
    read_records,
    subset_of,
)
from ratouch.eval.judge.shifts import (
    CHANCE_TOLERANCE,
    SHIFTS,
    antonym_answer,
    chance_level,
    generic_words,
    length_effect,
    style_shift,
    style_shifts,
)
from ratouch.eval.judge.stats import (
    BOOTSTRAP_SAMPLES,
    format_stats,
    format_summary,
    judge_results,
    mean_ci,
    score_stats,
)
from ratouch.eval.judge.validation import (
    GPT4_INTERRUN_SPEARMAN,
    TARGETS,
    format_validation,
    leave_one_system_out,
    validate_judge,
)
from ratouch.vocabulary import TVL_QUESTION  # the question the LLM judge asks

__all__ = [
    "ANTONYM_GROUPS", "BOOTSTRAP_SAMPLES", "CHANCE_TOLERANCE", "CONFIG_PATH", "DATA_DIR_ENV",
    "EVAL_KEY", "FEATURES", "GPT4_INTERRUN_SPEARMAN", "IGNORE_BELOW", "JUDGE_PROMPT",
    "JUDGE_SYSTEM", "LABEL_KEY", "LLMJudge", "LLMJudgeConfig", "MAX_SCORE", "MIN_SCORE", "MODELS",
    "NON_TACTILE", "NO_RATES", "OfflineJudge", "PSEUDO_ANSWERS", "RESPONSE_KEY", "SHIFTS",
    "SUBSETS", "SYNONYM", "TARGETS", "TVL_QUESTION", "WordRates", "answer_rates", "antonym_answer",
    "antonymy", "build_judge_prompt", "chance_level", "check_records", "compare_judges",
    "explain_results", "fit_calibration", "fit_offline_judge", "format_compare", "format_explain",
    "format_stats", "format_summary", "format_validation", "generic_words", "heldout_split",
    "informativeness", "judge_data_dir", "judge_features", "judge_results", "label_fit_rates",
    "leave_one_system_out", "length_effect", "load_offline_config", "load_tvl_results", "mean_ci",
    "parse_gpt_score", "read_records", "score_stats", "similarity", "style_shift", "style_shifts",
    "subset_of", "validate_judge", "word_table", "write_offline_config",
]
