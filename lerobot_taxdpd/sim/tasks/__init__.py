"""The benchmark's tasks by name."""

from __future__ import annotations

from lerobot_taxdpd.sim.tasks.base import BuiltScene, GoalMode, PlacementTask
from lerobot_taxdpd.sim.tasks.book_shelf import BookShelfTask
from lerobot_taxdpd.sim.tasks.can_cabinet import CanCabinetTask
from lerobot_taxdpd.sim.tasks.insertion import InsertionTask
from lerobot_taxdpd.sim.tasks.mug_rack import MugRackTask

_TASKS: dict[str, PlacementTask] = {
    task.name: task
    for task in (
        MugRackTask("mug_easyrack", 1, 1, "mug_rack_easy_single", "hang the mug on the rack's peg"),
        MugRackTask("mug_medrack", 1, 2, "mug_rack_med_single", "hang the mug on one of the rack's two pegs"),
        MugRackTask("mug_multi_medrack", 3, 2, "mug_rack_med_multi", "hang the mug on a peg of one of the racks"),
        BookShelfTask(),
        CanCabinetTask(),
        InsertionTask(
            "insert_waterproof", "waterproof", False, "insert the round waterproof connector into its socket"
        ),
        InsertionTask("insert_dsub25", "dsub25", False, "insert the D-sub 25 connector into its socket"),
        InsertionTask("insert_ssd", "ssd", False, "insert the SSD card into its slot"),
        InsertionTask(
            "insert_waterproof_multi",
            "waterproof",
            True,
            "insert the waterproof connector into one of the two matching sockets",
        ),
    )
}


def get_task(name: str) -> PlacementTask:
    """The task called `name`; the error lists the valid names."""
    try:
        return _TASKS[name]
    except KeyError:
        raise ValueError(f"task: unknown task {name!r}; choose one of {', '.join(_TASKS)}") from None


def task_names() -> list[str]:
    return list(_TASKS)


__all__ = ["BuiltScene", "GoalMode", "PlacementTask", "get_task", "task_names"]
