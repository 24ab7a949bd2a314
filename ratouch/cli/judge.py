"""`ratouch judge`: score TVL-format results with the offline or LLM judge, explain, compare,
validate and refit the offline judge.
"""

from __future__ import annotations

import argparse
import json

from ratouch.cli.common import usage
from ratouch.eval import judge as J
from ratouch.eval.tvl import oracle_length_effect
from ratouch.files import write_json_atomic


def make_judge(args: argparse.Namespace) -> J.OfflineJudge | J.LLMJudge:
    if args.judge == "llm":
        return J.LLMJudge(J.LLMJudgeConfig.from_env(args.endpoint, args.model, args.api_key_env))
    return J.OfflineJudge()


def _check_judge_args(args: argparse.Namespace) -> None:
    files = args.file
    if not (files or args.validate or args.fit or args.length_effect):
        raise usage("judge needs FILE --out SCORED.json, FILE --explain, FILE --compare, "
                    "--validate or --fit")
    if (args.explain or args.compare) and not files:
        raise usage("--explain and --compare need an input FILE")
    if len(files) > 1 and not args.compare:
        raise usage(f"{len(files)} files given; only --compare takes several")
    if files and not (args.out or args.explain or args.compare):
        raise usage("judge FILE needs --out SCORED.json (or --explain / --compare)")
    if args.out and (not files or args.compare):
        raise usage("--out needs exactly one input FILE (and no --compare)")


def run(args: argparse.Namespace) -> int:
    _check_judge_args(args)
    report: dict = {}
    llm = (J.LLMJudge(J.LLMJudgeConfig.from_env(args.endpoint, args.model, args.api_key_env))
           if args.compare else None)  # configuration errors before any work
    judge = make_judge(args) if args.out else None
    records = {f: J.read_records(f) for f in args.file}  # checked before anything is written
    if args.fit:
        report["fit"] = str(J.write_offline_config(J.fit_offline_judge()))
    scored = None
    if judge is not None:  # given --out
        scored, report["results"] = J.judge_results(records[args.file[0]], judge)
    if args.explain:
        report["explain"] = {f: J.explain_results(r) for f, r in records.items()}
    if llm is not None:
        report["compare"] = J.compare_judges(records, llm)
    if args.validate:
        report["validation"] = J.validate_judge()
    if args.length_effect:
        # imported here, not at the top: it imports torch and the world, which the rest of
        # `ratouch judge` does without

        report["length_effect"] = oracle_length_effect()
    if scored is not None:
        write_json_atomic(args.out, scored)
        report["out"] = str(args.out)
    if args.json:
        print(json.dumps(report, indent=1))
    else:
        _print_judge_report(J, args, report)
    return 0


def _print_judge_report(J, args: argparse.Namespace, report: dict) -> None:
    if "fit" in report:
        print(f"wrote the offline judge calibration to {report['fit']}")
    if "results" in report:
        r = report["results"]
        print(f"{r['judge']} judge on {args.file[0]}: {r['n']} responses, {r['n_failed']} failed "
              f"(scored 1)")
        print(J.format_summary(r))
        print(f"wrote {args.out}")
    for name, explained in report.get("explain", {}).items():
        print(f"offline judge on {name}, answer by answer:")
        print(J.format_explain(explained))
    if "compare" in report:
        print("offline judge vs LLM judge:")
        print(J.format_compare(report["compare"]))
    if "validation" in report:
        print(J.format_validation(report["validation"]))
    if "length_effect" in report:
        le = report["length_effect"]
        print("material oracle on the world's test split (the n heaviest profile words):")
        for n, s in le["stats"].items():
            print(f"  {n} adjectives: {J.format_stats(s)}")
        print(f"  spread {le['spread']:.3f}")
