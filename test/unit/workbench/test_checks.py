"""The checks of a finding as registered objects (wind_shaper.workbench.checks): every check
says what it asks and how it refuses, and the report lists each check's result for each effect
the selection added."""
import inspect

import pytest

from wind_shaper.workbench.checks import CHECKS, Check, CheckResult, register_check
from wind_shaper.workbench.commands import diagnose_command
from wind_shaper.workbench.diagnose import Diagnosis


def test_every_registered_check_has_a_name_a_question_and_a_refusal():
    assert list(CHECKS)[:2] == ['guard', 'across_sweeps']  # the guard, then the check across sweeps
    settings = inspect.signature(Diagnosis).parameters
    for name, check in CHECKS.items():
        assert isinstance(check, Check) and check.name == name
        assert check.question.endswith('?'), name
        assert check.refusal, name
        assert check.stage in ('candidate', 'sweeps', 'finding'), name
        assert not check.setting or check.setting in settings, (name, check.setting)
        assert not check.second_chance_for or check.second_chance_for in CHECKS, name
        assert name in repr(check)


def test_the_stages_run_in_one_line_and_none_calls_back_into_the_diagnosis():
    """Diagnosis.fit runs the stages in order, each taking and returning the case; no module
    below it (a stage, a check, a helper) imports diagnose.py, so nothing comes back to it."""
    import ast
    from pathlib import Path

    from wind_shaper.workbench import diagnose
    assert [s.__module__.removeprefix('wind_shaper.workbench.') for s in diagnose.STAGES] == [
        'time_checks.stage', 'selection', 'checks.run', 'family_forms', 'rest', 'verdict']
    root = Path(diagnose.__file__).parent
    callers = {'__init__.py', 'diagnose.py', 'commands.py', 'add.py', 'suggest.py'}  # above it
    importers = []
    for path in sorted(root.rglob('*.py')):
        if path.relative_to(root).as_posix() in callers:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or '').endswith('diagnose'):
                importers.append(path.relative_to(root).as_posix())
    assert importers == []


def test_a_new_check_is_one_class_registered_by_name():
    @register_check
    class Nothing(Check):
        name = 'nothing_for_the_test'
        question = 'Does it do nothing?'
        refusal = 'it does something'

        def judge_one(self, case, rnd, i):
            return self.result(True, {})
    try:
        assert isinstance(CHECKS['nothing_for_the_test'], Nothing)
        assert list(CHECKS)[-1] == 'nothing_for_the_test'  # runs last
    finally:
        del CHECKS['nothing_for_the_test']
    with pytest.raises(TypeError):
        register_check(type('NoQuestion', (Check,), {'name': 'no_question', 'refusal': 'x'}))


def test_a_check_result_says_passed_refused_or_not_run():
    assert [CheckResult('guard', p).state for p in (True, False, None)] == ['passed', 'refused', 'not run']
    doc = CheckResult('guard', False, {'dbic': -3.0}, 'BIC falls only 3.0').to_json()
    assert doc['question'] == CHECKS['guard'].question and doc['result'] == 'refused'


@pytest.mark.slow
def test_the_report_lists_every_check_for_each_finding(diagnosed):
    d, _ = diagnosed('weak_fan')
    doc = d.to_json()
    assert [c['check'] for c in doc['checks']] == list(CHECKS)
    (finding,) = doc['findings']
    assert [c['check'] for c in finding['checks']] == list(CHECKS)
    results = {c['check']: c['result'] for c in finding['checks']}
    # a reported finding passed every check that applies to it; none refused it
    assert 'refused' not in results.values()
    assert results['guard'] == results['across_sweeps'] == results['thrust_curves'] == 'passed'
    assert results['specific'] == 'not run'  # a gain is not checked for being specific
    guard = finding['checks'][0]['numbers']
    assert guard['heldout_gain'] >= 0.2 and guard['dbic'] <= -10
    text = d.checks_text()
    assert all(f'- {name} (' in text for name in CHECKS)


@pytest.mark.slow
def test_a_refused_effect_shows_which_check_refused_it_in_the_report(wb_setup, reference, sim_data,
                                                                     tmp_path):
    # a blocked patch of the straightener: the selection adds an effect that patches it, and a
    # check refuses it; the report says which, and that the later checks were not reached
    data, _ = sim_data('honeycomb_blockage')
    d = diagnose_command(reference, data, wb_setup.geometry, tmp_path)
    assert d.demoted_, d.summary()
    for t in d.demoted_:
        states = [t.checks[name].state for name in CHECKS]
        assert states.count('refused') >= 1 and states[0] == 'passed'
        first = states.index('refused')
        refused_by = list(CHECKS)[first]
        if refused_by not in ('across_sweeps', 'beside_discrepancy'):
            assert t.checks[refused_by].why in t.reasons
    report = (tmp_path / 'report.md').read_text()
    assert 'Every check of each effect the selection added' in report
    assert all(name in report for name in CHECKS)
