"""A stand-in for viser's server, GUI and scene (a third-party library): what the map and its panels
add to them is kept, to be read back, and a button can be pressed as a websocket client presses it."""

from __future__ import annotations

import contextlib
from types import SimpleNamespace
from typing import Any


class Handle(SimpleNamespace):
    def __init__(self, **kw: Any) -> None:
        super().__init__(**{"visible": True, "disabled": False, "hint": None, "callbacks": [], **kw})

    def on_click(self, cb: Any) -> Any:
        self.callbacks.append(cb)
        return cb

    on_update = on_click

    def press(self) -> None:
        """What a websocket client does when it clicks (viser calls the callbacks, whatever the page shows)."""
        for cb in self.callbacks:
            cb(None)


class FakeGui:
    def __init__(self) -> None:
        self.handles: dict[str, Handle] = {}

    def _add(self, label: str, **kw: Any) -> Handle:
        handle = Handle(label=label, **kw)
        self.handles[label] = handle
        return handle

    def add_folder(self, label: str) -> contextlib.AbstractContextManager:
        return contextlib.nullcontext()

    def add_text(self, label: str, value: str, **kw: Any) -> Handle:
        return self._add(label, value=value)

    def add_number(self, label: str, value: float, **kw: Any) -> Handle:
        return self._add(label, value=value, min=None, max=None, step=kw.get("step"))

    def add_dropdown(self, label: str, options: list, initial_value: Any = None, **kw: Any) -> Handle:
        return self._add(label, value=initial_value or options[0], options=list(options))

    def add_checkbox(self, label: str, value: bool, **kw: Any) -> Handle:
        return self._add(label, value=value)

    def add_button(self, label: str, **kw: Any) -> Handle:
        return self._add(label, visible=kw.get("visible", True))

    def add_markdown(self, content: str, **kw: Any) -> Handle:
        return Handle(content=content)

    add_html = add_markdown


class FakeScene:
    """viser's scene: every ``add_*`` keeps its node (name, arguments) until the node is removed."""

    def __init__(self) -> None:
        self.nodes: dict[str, Handle] = {}

    def __getattr__(self, method: str) -> Any:
        def add(name: str = "", *args: Any, **kw: Any) -> Handle:
            handle = Handle(method=method, name=name, args=args, **kw)
            handle.remove = lambda: self.nodes.pop(name, None)
            self.nodes[name] = handle
            return handle

        return add


def fake_server() -> SimpleNamespace:
    return SimpleNamespace(
        scene=FakeScene(), initial_camera=SimpleNamespace(position=None, look_at=None, fov=None)
    )


class FakeCamera(SimpleNamespace):
    """A browser's camera: what the panel sets on it is kept; ``report`` is the browser telling its view."""

    def __init__(self) -> None:
        super().__init__(position=None, look_at=None, fov=None, far=None, up_direction=None, callbacks=[])

    def on_update(self, cb: Any) -> Any:
        self.callbacks.append(cb)
        return cb

    def report(self, width: int, height: int) -> None:
        self.image_width, self.image_height = width, height
        for cb in self.callbacks:
            cb(self)


def fake_client(client_id: int = 1) -> SimpleNamespace:
    """A browser's connection: its own GUI and camera (no scene of its own: clicks are not simulated)."""
    return SimpleNamespace(
        client_id=client_id, gui=FakeGui(), scene=None, camera=FakeCamera(), atomic=contextlib.nullcontext
    )
