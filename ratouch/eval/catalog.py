"""The names the evaluations use: the paper's experiments, with one line each (what `ratouch
eval <name>` runs), and the two systems they compare.

Kept apart from `ratouch.eval.experiments` (which imports the models) so that the command
line can list the experiments without loading torch. `experiments.EXPERIMENTS` implements
exactly these names (checked when it is imported).
"""

EXPERIMENT_HELP: dict[str, str] = {
    "table1": "Table 1 (the world's version): the encoder's baseline vs RA-Touch over corpus "
              "sizes.",
    "table2": "Table 2: retriever and integrator ablation.",
    "table3": "Table 3: what the corpus's text side holds.",
    "table4": "Table 4: retrieval query x key.",
    "table5": "Table 5: integrate retrieved images, texts or both.",
    "fig3": "Figure 3: corpus scale (stratified subsets of the corpus).",
    "fig6": "Figure 6: number of retrieved neighbours K.",
    "fig5": "Figure 5: PCA of the joint queries, alignment loss only vs alignment + stability.",
    "table6": "Table 6 (not in the paper): materials missing from the paired training data.",
}

#: The two systems every evaluation compares, by name: the baseline (no retrieval) and
#: RA-Touch. The one spelling of a system's name: `ratouch eval tvl --system`, the "system"
#: of a TVL result record, the stress report's series (`ratouch.eval.answer.answer_split`).
#: Where RA-Touch's output stands in a JSON result -- a query's ``description.ra_touch``, a
#: failure table's column, the controls' and the premise's answer sets -- its key is spelled
#: "ra_touch": a public output name, a role apart from the system's name.
SYSTEMS = ("baseline", "ra-touch")
BASELINE, RA_TOUCH = SYSTEMS

#: The second-stage arms `ratouch eval premise` can judge beside the paper's RA-Touch, by
#: name: "tokens" (each retrieved caption embedding a prefix token,
#: `ratouch.model.neighbour_tokens`) and "text" (the retrieved captions written into the
#: prompt, `ratouch.model.neighbour_text`). `premise.ARMS` implements exactly these.
ARM_NAMES = ("tokens", "text")
