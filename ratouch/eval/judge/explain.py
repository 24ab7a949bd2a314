"""Explaining the offline judge's scores word by word, and comparing it with an LLM judge on the
user's own result files."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ratouch.eval.judge.features import answer_rates
from ratouch.eval.judge.llm import LLMJudge
from ratouch.eval.judge.offline import OfflineJudge
from ratouch.eval.judge.records import LABEL_KEY, RESPONSE_KEY, check_records
from ratouch.eval.judge.stats import judge_results, spearman


def explain_results(records: list[dict], judge: OfflineJudge | None = None) -> list[dict]:
    """Per record (one system's answers): label, answer, per-word table and score."""
    judge = judge if judge is not None else OfflineJudge()
    check_records(records)
    rates = answer_rates(r[RESPONSE_KEY] for r in records)
    return [judge.explain(r[LABEL_KEY], r[RESPONSE_KEY], rates) for r in records]


def format_explain(explained: Sequence[dict]) -> str:
    """One block per answer: score, label, then each word with its status and weight."""
    lines = []
    for i, e in enumerate(explained):
        lines.append(f"[{i}] score {e['score']:.2f}  label: {', '.join(e['label'])}")
        if not e["words"]:
            lines.append("    (no adjectives: failed answer, scored 1)")
        for t in e["words"]:
            match = (f" ~ {t['label_word']} (sim {t['similarity']:.2f})"
                     if t["status"] in ("matched", "ignored") and t["label_word"] else "")
            clash = f" clash {t['clash']:.2f}" if t["clash"] else ""
            lines.append(f"    {t['word']:<14}{t['status']:<12}weight {t['weight']:.2f} "
                         f"(label rate {t['label_rate']:.2f}, system rate {t['system_rate']:.2f})"
                         f"{match}{clash}")
    return "\n".join(lines)


def compare_judges(files: Mapping[str, list[dict]], llm: LLMJudge,
                   offline: OfflineJudge | None = None) -> dict:
    """Agreement of the offline judge with an LLM judge on the user's own result files.

    Returns per file n, both means and their difference (offline - LLM), the Spearman rho of
    the per-answer scores (None where either judge gives one constant score), the pooled rho,
    and the LLM judge's request counters.
    """
    offline = offline if offline is not None else OfflineJudge()
    per_file, all_off, all_llm = {}, [], []
    for name, records in files.items():
        off = [r[offline.key] for r in judge_results(records, offline)[0]]
        lm = [r[llm.key] for r in judge_results(records, llm)[0]]
        per_file[name] = {"n": len(records), "offline_mean": float(np.mean(off)),
                          "llm_mean": float(np.mean(lm)),
                          "mean_diff": float(np.mean(off) - np.mean(lm)),
                          "spearman": _safe_spearman(off, lm)}
        all_off += off
        all_llm += lm
    return {"files": per_file, "pooled_spearman": _safe_spearman(all_off, all_llm),
            "llm": llm.stats()}


def _safe_spearman(a: Sequence[float], b: Sequence[float]) -> float | None:
    if len(a) < 2 or len(set(a)) < 2 or len(set(b)) < 2:
        return None
    return spearman(a, b)


def format_compare(r: dict) -> str:
    """The offline-vs-LLM agreement table."""
    def rho(x):
        return "-" if x is None else f"{x:.3f}"

    lines = [f"{'file':<40}{'n':>5}{'offline':>9}{'LLM':>8}{'diff':>8}{'rho':>7}"]
    for name, s in r["files"].items():
        lines.append(f"{name[-40:]:<40}{s['n']:>5}{s['offline_mean']:>9.3f}{s['llm_mean']:>8.3f}"
                     f"{s['mean_diff']:>+8.3f}{rho(s['spearman']):>7}")
    lines.append(f"pooled Spearman rho {rho(r['pooled_spearman'])}; LLM requests "
                 f"{r['llm']['n_requests']}, errors {r['llm']['n_errors']}, fallbacks to the "
                 f"offline judge {r['llm']['n_fallbacks']}")
    return "\n".join(lines)
