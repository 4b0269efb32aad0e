"""The viewer's keys (:data:`~holo_viewer.gui.viewer_config.KEYS`) and the typed value entry (``Return``)."""

from __future__ import annotations

from typing import Any, Callable


from ..errors import InputError


class KeysMixin:
    """Part of :class:`~holo_viewer.gui.viewer.HoloViewer` (uses its attributes; not used alone)."""

    def quit(self) -> None:
        self._quit = True

    def _key_actions(self) -> dict[str, Callable[[], Any]]:
        return {"h": self.toggle_help, "q": self.quit, "m": self.toggle_mesh, "l": self.toggle_wireframe,
                "g": self.toggle_gaussians, "c": self.cycle_glyph_color, "o": self.toggle_frusta,
                "p": self.cycle_panel, "bracketright": lambda: self.zoom_native(1),
                "bracketleft": lambda: self.zoom_native(-1), "s": self.toggle_splats, "v": self.toggle_look_through, "r": self.reset_camera, "z": self.head_closeup, "0": self.reset_face, "Left": lambda: self.step_view(-1),
                "Right": lambda: self.step_view(1), "Return": self.start_entry, "KP_Enter": self.start_entry,
                "k": self.export_quilt, "n": self.export_native, "x": self.export_sweep_video, "X": lambda: self.export_sweep_video("pain"),
                "i": self.save_screenshot, "braceright": lambda: self.resize_panels(1),
                "braceleft": lambda: self.resize_panels(-1)}

    def press_key(self, keysym: str, char: str = "") -> None:
        """Handle one key press (what the window does for a real key; tests may call it directly)."""
        if self._entry is not None:
            self._entry_key(keysym, char)
            return
        action = self._key_actions().get(keysym)
        if action is not None:
            self._guarded(action)

    def _on_key(self, obj: Any, _event: str) -> None:
        code = obj.GetKeyCode()
        self.press_key(obj.GetKeySym() or "", code if isinstance(code, str) else "")

    def start_entry(self) -> None:
        """Start typing a value: ``NAME VALUE`` (e.g. ``pain 0.6``, ``au9 1``, ``view 30``), Return applies."""
        self._entry = ""
        self._show_entry()

    def _show_entry(self) -> None:
        if self._entry is None:
            self.entry_actor.SetInput("")
            self.entry_actor.SetVisibility(False)
        else:
            names = ", ".join(s.entry_name for s in list(self._specs.values())[:6]) + ", ..."
            self.entry_actor.SetInput(f"set: {self._entry}_\n(NAME VALUE, e.g. pain 0.6; {names}; Esc cancels)")
            self.entry_actor.SetVisibility(True)
        self._render()

    def _entry_key(self, keysym: str, char: str) -> None:
        if keysym == "Escape":
            self._entry = None
        elif keysym in ("Return", "KP_Enter"):
            text, self._entry = self._entry, None
            self._show_entry()
            self._guarded(self.apply_entry, text)
            return
        elif keysym == "BackSpace":
            self._entry = self._entry[:-1]
        elif char and (char.isalnum() or char in " ._-+"):
            self._entry += char
        self._show_entry()

    def find_slider(self, name: str) -> str:
        """The slider key for ``name``: a key (``pain``), an AU code (``au9``) or a title prefix."""
        n = name.strip().lower()
        if n in self._specs:
            return n
        for key, s in self._specs.items():
            if n in s.aliases:
                return key
        hits = [k for k, s in self._specs.items() if s.title.lower().startswith(n)]
        if len(hits) == 1:
            return hits[0]
        known = ", ".join(s.entry_name for s in self._specs.values())
        raise InputError(f"value entry: no slider named {name!r} (expected one of {known})")

    def apply_entry(self, text: str) -> None:
        """Set a slider from typed text ``"NAME VALUE"`` as if it had been dragged and released there."""
        parts = text.replace("=", " ").split()
        if len(parts) != 2:
            raise InputError(f"value entry: expected 'NAME VALUE' (e.g. pain 0.6), found {text!r}")
        key = self.find_slider(parts[0])
        try:
            value = float(parts[1])
        except ValueError:
            raise InputError(f"value entry: {parts[1]!r} is not a number") from None
        spec = self._specs[key]
        lo, hi = spec.rng
        if not lo <= value <= hi:
            raise InputError(f"{spec.title}: expected {spec.fmt % lo}..{spec.fmt % hi}, found {parts[1]}")
        spec.set_value(value)
        self._on_slider_release(spec)

