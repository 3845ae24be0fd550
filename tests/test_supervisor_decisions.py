"""The supervisor's decisions on restarts, the table lock and its children's events, from the run's state: no process."""

from types import SimpleNamespace

import pytest

from pbo_runtime.config.model import RestartPolicy, RtpuSpec
from pbo_runtime.errors import PboError
from pbo_runtime.ipc import messages
from pbo_runtime.ipc.task_statistics import TaskStatistics
from pbo_runtime.reports.run_records import StableEpisode
from pbo_runtime.supervisor.children import Child, death_failure
from pbo_runtime.supervisor.event_ledger import ErrorWords, error_words
from pbo_runtime.supervisor.events import EventHandling, change_seen, state_served
from pbo_runtime.supervisor.failures import RtpuDied, RunFailure
from pbo_runtime.supervisor.lock_watch import LockVerdict, holder_alive, lock_verdict
from pbo_runtime.supervisor.restarts import RestartPlan, count_death, may_restart, restart_plan
from tests.support import EventsHeard

POLICY = RestartPolicy(max=3, within=10.0)
RTPUS = [RtpuSpec("rtpu0", 0, restart=POLICY), RtpuSpec("rtpu1", 1)]


# --- whether a death is restarted ------------------------------------------------------------


@pytest.mark.parametrize(("role", "table_made", "stopping", "restarted"), [
    ("rtpu0", True, "", True),
    ("rtpu1", True, "", False),  # no policy: the run stops
    ("plant", True, "", False),  # the plant is never restarted
    ("rtpu0", False, "", False),  # before the table exists: a start that failed
    ("rtpu0", True, "Ctrl-C", False),  # the run is stopping anyway
    ("rtpu9", True, "", False),  # not an RTPU of this subsystem
])
def test_only_an_rtpu_with_a_policy_is_restarted_and_only_while_the_run_goes_on(role, table_made, stopping, restarted):
    assert may_restart(role, RTPUS, table_made, stopping) is restarted


# --- the policy's count ----------------------------------------------------------------------


def test_the_deaths_past_max_within_the_window_stop_the_run():
    deaths: list[float] = []
    verdicts = []
    for at in (1.0, 2.0, 3.0, 4.0):
        deaths, past = count_death(deaths, at, POLICY)
        verdicts.append(past)
    assert verdicts == [False, False, False, True]
    assert deaths == [1.0, 2.0, 3.0, 4.0]


def test_a_death_that_left_the_window_is_no_longer_counted():
    deaths, past = count_death([1.0, 2.0, 3.0], 11.5, POLICY)  # 1.0 is 10.5 s before: out of the 10 s window
    assert (deaths, past) == ([2.0, 3.0, 11.5], False)


def test_a_policy_of_no_restart_stops_the_run_at_the_first_death():
    assert count_death([], 0.5, RestartPolicy(max=0, within=10.0)) == ([0.5], True)


def test_counting_leaves_the_deaths_it_was_given_alone():
    before = [1.0]
    count_death(before, 2.0, POLICY)
    assert before == [1.0]


# --- what a restart brings back --------------------------------------------------------------


STATES = {"traj": "ON", "pid": "ON", "spare": "OFF", "gone": "KILLED", "never": "NOT_CREATED"}
HOSTED = ["traj", "pid", "spare", "gone", "never"]


def test_a_restart_brings_back_what_was_alive_and_turns_on_what_was_on():
    assert restart_plan(HOSTED, STATES, "run") == RestartPlan(["traj", "pid", "spare"], ("traj", "pid"), "run")


def test_a_task_the_supervisor_never_heard_of_is_not_spawned():
    assert restart_plan(["traj", "late"], {"traj": "ERROR"}, "run") == RestartPlan(["traj"], (), "run")


def test_a_dynamic_switch_keeps_what_was_spawned_and_turns_on_the_new_configurations_members():
    plan = restart_plan(HOSTED, STATES, "hold", switching_to=["spare", "never"], static=False)
    assert plan == RestartPlan(["traj", "pid", "spare"], ("spare",), "hold")


def test_a_static_switch_spawns_only_the_new_configurations_members():
    plan = restart_plan(HOSTED, STATES, "hold", switching_to=["spare", "never"], static=True)
    assert plan == RestartPlan(["spare", "never"], ("spare", "never"), "hold")


# --- a holding of the table lock past its bound ----------------------------------------------


OWN = 100


@pytest.mark.parametrize(("pid", "state", "ours", "verdict"), [
    (0, "", False, LockVerdict("left", "dead", "it cannot be told who holds it; the run is stopped")),
    (OWN, "", False, LockVerdict("left", "dead", "it cannot be told who holds it; the run is stopped")),
    (200, "", True, LockVerdict("released", "dead")),  # gone: its lock is released
    (200, "Z", True, LockVerdict("released", "dead")),  # a zombie holds nothing
    (200, "T", True, LockVerdict("killed", "stopped")),  # a child stopped by SIGSTOP
    (200, "R", True, LockVerdict("killed", "running")),
    (300, "S", False, LockVerdict("left", "running",
                                  "it is not a process of this run, so it was not signalled; the run is stopped")),
    (300, "", False, LockVerdict("released", "dead")),  # any dead holder's lock is released
])
def test_a_wedged_lock_is_released_from_the_dead_and_taken_from_the_runs_own_never_from_another(pid, state, ours, verdict):
    assert lock_verdict(pid, OWN, state, ours) == verdict


@pytest.mark.parametrize(("state", "alive"), [("", False), ("Z", False), ("X", False), ("R", True), ("S", True),
                                              ("D", True), ("T", True), ("t", True)])
def test_only_a_live_holder_gets_a_last_look(state, alive):
    assert holder_alive(state) is alive


# --- what an event changes -------------------------------------------------------------------


def test_a_task_entering_error_is_told_once_and_the_error_words_follow_each_change():
    heard = EventsHeard()
    heard.hear("rtpu0", messages.StateChanged("pid", "ON"), messages.StateChanged("pid", "ERROR", "gain NaN"),
               messages.StateChanged("pid", "ERROR", "gain NaN"), messages.StateChanged("pid", "OFF"))
    assert heard.ledger.task_states == {"pid": "OFF"} and heard.ledger.task_errors == {"pid": "gain NaN"}
    assert heard.lines == ["task 'pid' on rtpu0 is in ERROR: gain NaN (operator intervention required: pbo clear pid)"]
    assert heard.handed == [("count_errors",), ("count_errors",)]  # into ERROR, out of it


def test_an_output_that_failed_is_one_fault_per_task():
    heard = EventsHeard()
    failed = messages.StateChanged("logger", "ERROR", "disk full", output_failed=True)
    heard.hear("rtpu1", failed, messages.StateChanged("logger", "OFF"), failed)
    assert heard.result.faults == ["task 'logger' on rtpu1 could not write its output: disk full"]


def test_a_switchs_reports_go_to_job_control_as_they_came():
    heard = EventsHeard()
    heard.hear("rtpu0", messages.Switched(3, "pd", 1.0, 1.001, 1.002, ["pid"], ["pd"], read_at=0.9),
               messages.Window(3, "robot", 0, 2), messages.FirstCycle(3, "pd", 1.0015))
    assert heard.handed == [("switched", "rtpu0", 3, 1.001, 1.002, ["pid"], ["pd"], 0.9), ("window", 3, "robot", 0, 2),
                            ("first_cycle", 3, "pd", 1.0015)]


def test_a_refusal_is_kept_for_the_waiter_and_told():
    heard = EventsHeard()
    heard.hear("rtpu0", messages.Refused("pid", "it is ON"))
    assert heard.ledger.refused == {"pid": "it is ON"}
    assert heard.lines == ["rtpu0 refused a signal for 'pid': it is ON"]


@pytest.mark.parametrize(("running", "faults"), [(True, 1), (False, 0)])
def test_a_plant_stall_is_a_fault_only_once_the_configuration_is_on(running, faults):
    heard = EventsHeard(running=running)
    heard.hear("plant", messages.PlantStalled(0.25, 3.0))
    assert len(heard.result.faults) == faults and len(heard.lines) == 1
    assert heard.lines[0].startswith("the plant did not run for 0.250 s")


def test_a_childs_crash_fails_the_run_with_its_trace():
    heard = EventsHeard()
    with pytest.raises(RunFailure, match=r"^rtpu1 crashed: ValueError: bad\nTraceback"):
        heard.hear("rtpu1", messages.Crashed("ValueError: bad", "Traceback ..."))


def test_what_concerns_other_parts_is_handed_on():
    heard = EventsHeard()
    heard.hear("rtpu0", messages.Staged(2, ""), messages.ChildExited("rtpu1", 4321),
               messages.Stats("pid", TaskStatistics(cycles=5)))
    assert heard.handed == [("staged", "rtpu0", 2, ""), ("child_exited",)]
    assert heard.ledger.stats == {"pid": TaskStatistics(cycles=5)}


def test_a_stable_episode_of_a_task_that_is_not_critical_says_the_critical_tasks_hold():
    heard = EventsHeard(not_critical=("receive",))
    heard.hear("rtpu0", messages.Stable("receive", True, 1.0, "", "module"), messages.Stable("receive", False, 1.5))
    assert heard.lines == [
        "task 'receive' has no fresh input (its cycle returned STABLE): the critical tasks hold until it has",
        "task 'receive' is back to its cycle after 500.0 ms"]
    assert heard.result.stable_episodes == [StableEpisode("receive", 1.0, 1.5, "", "module")]
    assert heard.ledger.stable == {} and heard.handed == [("count_errors",)] * 2


def test_an_episode_open_at_the_stop_is_ended_without_an_end():
    heard = EventsHeard()
    heard.hear("rtpu0", messages.Stable("robot", True, 2.0, "stale q_m", "stale"))
    heard.ledger.end_stable_episode("robot", None)
    assert heard.result.stable_episodes == [StableEpisode("robot", 2.0, None, "stale q_m", "stale")]


# --- which child died, and what that means ---------------------------------------------------


class FakeProcess:
    """A child's process as the death decision sees it: its pid only (no process is started)."""

    pid = 4321


@pytest.mark.parametrize(("role", "tasks", "code", "restartable", "failure", "message"), [
    ("rtpu0", ("pid", "log"), -9, True, RtpuDied,
     "RTPU 'rtpu0' (pid 4321) died (killed by SIGKILL) while hosting tasks: pid, log"),
    ("rtpu1", (), 3, False, RunFailure, "RTPU 'rtpu1' (pid 4321) died (exit status 3)"),
    ("plant", (), -11, False, RunFailure, "the plant (pid 4321) died (killed by SIGSEGV)"),
])
def test_a_childs_death_is_a_restart_only_where_its_policy_allows_and_says_who_and_how(
        role, tasks, code, restartable, failure, message):
    death = death_failure(Child(role, FakeProcess(), tasks), code, restartable)  # type: ignore[arg-type]
    assert type(death) is failure and str(death) == message


def test_a_restartable_death_carries_what_the_restart_needs():
    death = death_failure(Child("rtpu0", FakeProcess()), -6, True)  # type: ignore[arg-type]
    assert isinstance(death, RtpuDied) and (death.rtpu, death.pid, death.cause) == ("rtpu0", 4321, "killed by SIGABRT")


# --- when a wait for a task's state ends -----------------------------------------------------


@pytest.mark.parametrize(("event", "state", "ends"), [
    (messages.StateChanged("pid", "ON"), "ON", True),
    (messages.StateChanged("pid", "OFF"), "OFF", False),  # a change, but not to a state waited for
    (messages.StateChanged("log", "ON"), "ON", False),  # another task's change
    (messages.Refused("log", "it is ON"), "OFF", False),  # another task's refusal
    (messages.PlanPosted(), "ON", False),  # no change at all, even if the state already is one waited for
])
def test_a_wait_for_a_change_ends_on_the_tasks_own_change_into_a_state_waited_for(event, state, ends):
    assert change_seen("pid", {"ON", "ERROR"}, event, state) is ends


def test_a_refusal_of_the_tasks_signal_ends_the_wait_with_its_reason():
    with pytest.raises(PboError, match=r"^task 'pid': it is ON$"):
        change_seen("pid", {"ON"}, messages.Refused("pid", "it is ON"), "ON")


@pytest.mark.parametrize(("refused", "state", "answer"), [
    ({}, "ON", "ON"),
    ({"pid": "it is ON"}, "ON", "task 'pid': it is ON"),  # a refusal wins over the state
    ({}, "ERROR", "task 'pid' is ERROR after the signal, not OFF or ON"),
])
def test_a_served_signal_leaves_the_task_in_a_state_waited_for_or_fails(refused, state, answer):
    if answer == state:
        assert state_served("pid", {"ON", "OFF"}, refused, {"pid": state}, RunFailure) == state
    else:
        with pytest.raises(RunFailure, match=f"^{answer}$"):
            state_served("pid", {"ON", "OFF"}, refused, {"pid": state}, RunFailure)


# --- the table's error words -----------------------------------------------------------------


TASKS = {"robot": SimpleNamespace(critical=True), "pid": SimpleNamespace(critical=False),
         "receive": SimpleNamespace(critical=False)}


@pytest.mark.parametrize(("states", "stable", "words"), [
    ({"robot": "ON", "pid": "ON"}, {}, ErrorWords(0, 0, False)),
    ({"robot": "ON", "pid": "ERROR", "other": "ERROR"}, {}, ErrorWords(1, 0, True)),  # only the configuration's count
    ({}, {"receive": (1.0, "", "module")}, ErrorWords(0, 1, True)),  # a task that is not critical said it is not fresh
    ({}, {"robot": (1.0, "stale q_m", "stale")}, ErrorWords(0, 0, True)),  # a critical task's own hold
    ({}, {"pid": (1.0, "", "stale")}, ErrorWords(0, 0, True)),  # stale, not its module's word: not counted
])
def test_the_error_words_count_the_configurations_tasks_in_error_and_not_fresh(states, stable, words):
    assert error_words(["robot", "pid", "receive"], states, stable, TASKS) == words  # type: ignore[arg-type]


# --- a spawn's wait, on the real clock ---------------------------------------------------------


class SignalsSentToFake:
    """An RTPU's signal queue in a unit test: what was sent."""

    def __init__(self) -> None:
        self.sent: list[messages.TaskSignal] = []

    def signal(self, signal: messages.TaskSignal, timeout: float) -> None:
        self.sent.append(signal)


class EventsQueueFake:
    """The run's event queue in a unit test: the events given, in order, then nothing."""

    def __init__(self, *events: tuple[str, messages.Event]) -> None:
        self.events = list(events)

    def receive_event(self, timeout: float) -> tuple[str, messages.Event] | None:
        return self.events.pop(0) if self.events else None


def real_clock_event_handling(heard: EventsHeard, events: EventsQueueFake, rtpu0: SignalsSentToFake) -> EventHandling:
    clock = SimpleNamespace(signals_served_when_sent=False, serve=lambda rtpu, while_waiting: None)
    tasks = {name: SimpleNamespace(rtpu="rtpu0") for name in ("logger", "pid")}
    return EventHandling(clock, heard.ledger, heard.result, {"rtpu0": rtpu0}, tasks, lambda: events,  # type: ignore[arg-type]
                         check_children=lambda: None, stop_requested=lambda: "", mark=lambda role: None, say=heard.lines.append)


@pytest.mark.parametrize("answer", ["OFF", "KILLED"])
def test_a_task_spawned_again_under_a_killed_tasks_name_is_answered_by_its_own_event_not_the_old_state(answer):
    heard = EventsHeard()
    heard.hear("rtpu0", messages.StateChanged("logger", "KILLED"))  # the task of that name killed before
    events = EventsQueueFake(("rtpu0", messages.StateChanged("pid", "ON")),  # another task's event comes first
                             ("rtpu0", messages.StateChanged("logger", answer)))
    rtpu0 = SignalsSentToFake()
    handling = real_clock_event_handling(heard, events, rtpu0)
    assert handling.spawn_and_wait("logger") == answer
    assert rtpu0.sent == [messages.Spawn("logger")] and events.events == []  # it waited for the new task's own event
