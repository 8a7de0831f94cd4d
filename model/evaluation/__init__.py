"""Evaluation of transition methods on fixed cases of a split (RSMT paper Sec. 5; reference doc Sec. 6).

Modules, one idea each: :mod:`~model.evaluation.cases` (what is evaluated),
:mod:`~model.evaluation.reference` (training-split statistics the metrics need),
:mod:`~model.evaluation.methods` (bundles and baselines behind one interface),
:mod:`~model.evaluation.scoring` (metrics of one variant), :mod:`~model.evaluation.style_scores`
(style accuracy and FMD from the style classifier), :mod:`~model.evaluation.runner` (the whole
run), :mod:`~model.evaluation.report` (Markdown and JSON) and :mod:`~model.evaluation.plots`
(PNG figures and the contact sheet). The command is ``rsmt eval`` (:mod:`rsmt_cli.eval_commands`).
"""

from model.evaluation.cases import VARIANTS, CaseSet, EvalCase, Variant, build_cases
from model.evaluation.methods import resolve_method
from model.evaluation.runner import EvalRun, EvalSettings, evaluate

__all__ = ["VARIANTS", "CaseSet", "EvalCase", "EvalRun", "EvalSettings", "Variant", "build_cases", "evaluate",
           "resolve_method"]
