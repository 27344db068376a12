"""Which work comes next, and what is done.

The schedule hands out, in order: the offline caustic pre-pass (if any),
then sample ranges [s0, s0 + n) until every pixel has the job's uniform
samples (ranges of spp_per_map samples, one photon-map iteration each, when
progressive), then the parts of adaptive rounds the driver adds. An item that
failed goes back to the front. Its position (`state()`) is plain data, so a
checkpoint can hold it and a resumed render continue from it.
"""

from __future__ import annotations

import numpy as np

from .job import RenderJob, WorkItem


class Schedule:
    def __init__(self, job: RenderJob):
        self.job = job
        self.next = 0              # first sample not yet handed out
        self.prepass_done = not job.prepass_spp
        self.prepass_out = False
        self.redo: list[WorkItem] = []
        self.round_items: list[WorkItem] = []
        self.rounds = 0            # adaptive rounds finished
        self.maps = 0              # progressive photon maps the adaptive rounds gathered from
        self.adaptive_over = job.adaptive is None
        self.out = 0               # items handed out and not yet done or failed
        self.stopped = False

    # --- handing out ------------------------------------------------------------------
    def take(self, n: int) -> WorkItem | None:
        """The next item; a sample range gets at most n samples per pixel."""
        if self.stopped:
            return None
        if self.redo:
            return self._out(self.redo.pop(0))
        job = self.job
        if not self.prepass_done and not self.prepass_out:
            self.prepass_out = True
            return self._out(WorkItem("prepass", 0, job.prepass_spp))
        if self.next < job.uniform_spp:
            s0 = self.next
            per_map = job.spp_per_map
            n = per_map if per_map else max(1, int(n))
            n = min(n, job.uniform_spp - s0)
            self.next = s0 + n
            return self._out(WorkItem("samples", s0, n, iteration=s0 // per_map if per_map else 0))
        if self.round_items:
            return self._out(self.round_items.pop(0))
        return None

    def _out(self, item):
        self.out += 1
        return item

    def done(self, item: WorkItem):
        self.out -= 1
        if item.kind == "prepass":
            self.prepass_done = True

    def failed(self, item: WorkItem):
        """Give the item back: it is handed out again, first."""
        self.out -= 1
        self.redo.append(item)

    def requeue(self, items):
        """Items done on a device whose sums were lost: they are done again."""
        for it in items:
            if it.kind == "prepass":
                self.prepass_done = False
            self.redo.append(it)

    def stop(self):
        self.stopped = True

    # --- adaptive rounds ------------------------------------------------------------
    def add_round(self, items):
        self.round_items = list(items)

    def round_done(self):
        self.rounds += 1

    # --- where it stands --------------------------------------------------------------
    @property
    def uniform_left(self) -> int:
        """Samples per pixel of the uniform phase not yet handed out."""
        return self.job.uniform_spp - self.next

    @property
    def idle(self) -> bool:
        """Nothing out and nothing left to hand out until the driver adds a round."""
        return self.out == 0 and not self.redo and not self.round_items and self.prepass_done and \
            self.next >= self.job.uniform_spp

    @property
    def finished(self) -> bool:
        return self.idle and self.adaptive_over

    def state(self) -> dict:
        """The position (only meaningful with nothing out, as at a checkpoint)."""
        if self.out:
            raise RuntimeError("a schedule's position is only defined with no work out")
        return {"next": self.next, "prepass_done": self.prepass_done, "rounds": self.rounds, "maps": self.maps,
                "adaptive_over": self.adaptive_over, "redo": [_item_state(i) for i in self.redo + self.round_items]}

    @classmethod
    def from_state(cls, job: RenderJob, st: dict) -> "Schedule":
        s = cls(job)
        s.next = int(st["next"])
        s.prepass_done = bool(st["prepass_done"]) or not job.prepass_spp
        s.rounds = int(st["rounds"])
        s.maps = int(st.get("maps", s.rounds))  # checkpoints of one map per round
        s.adaptive_over = bool(st["adaptive_over"])
        s.redo = [_item_from_state(d) for d in st["redo"]]
        return s


def _item_state(it: WorkItem) -> dict:
    d = {"kind": it.kind, "s0": it.s0, "n": it.n, "iteration": it.iteration, "round": it.round}
    if it.pixels is not None:
        d["pixels"] = it.pixels.tolist()
        d["jobs"] = it.jobs.tolist()
    return d


def _item_from_state(d: dict) -> WorkItem:
    px = np.array(d["pixels"], dtype=np.uint32) if "pixels" in d else None
    jb = np.array(d["jobs"], dtype=np.uint32).reshape(-1, 4) if "jobs" in d else None
    return WorkItem(d["kind"], d["s0"], d["n"], d["iteration"], px, jb, d["round"])
