"""Confining a child's writes to a few folders with Linux's Landlock (kernel 5.13 and later, no
privileges needed): `hovr render-blend` runs Blender on an untrusted .blend, whose datablocks can
name paths Blender writes to while it renders (a fluid or point cache, a bake, an export), so its
Blender may create, change or remove files only under the output folder, its own private
temporary folder and Warp's kernel cache (distributed/blender_frames.py), write to the devices a
renderer opens (/dev/null, the GPU's) and make files in /dev/shm (shared memory). Reading stays
unrestricted. The rule holds for the child and everything it starts, and cannot be lifted.

    ruleset = write_ruleset([out_folder, temp_folder])      # in the parent (None: not available)
    subprocess.Popen(..., preexec_fn=lambda: restrict_self(ruleset))
    os.close(ruleset)

The ruleset is built in the parent, where errors can be reported; the child only enforces it
(PR_SET_NO_NEW_PRIVS, then landlock_restrict_self) between fork and exec. Where Landlock is
missing (another system, an older kernel, a kernel built without it), `write_ruleset` returns None
and the caller relies on its other checks (ui/batch.py refuses a .blend whose datablocks would
write outside). `abi()` tells which version the kernel has: rights it does not know are left out.
"""
from __future__ import annotations

import ctypes
import os
import struct
import sys

# linux/landlock.h
_CREATE_RULESET_VERSION = 1
_RULE_PATH_BENEATH = 1
_SYSCALLS = {"x86_64": (444, 445, 446), "aarch64": (444, 445, 446)}  # create_ruleset, add_rule, restrict_self
_PR_SET_NO_NEW_PRIVS = 38

WRITE_FILE = 1 << 1
REMOVE_DIR, REMOVE_FILE = 1 << 4, 1 << 5
MAKE_CHAR, MAKE_DIR, MAKE_REG, MAKE_SOCK, MAKE_FIFO, MAKE_BLOCK, MAKE_SYM = (1 << k for k in range(6, 13))
REFER = 1 << 13  # ABI 2: linking or renaming across folders
TRUNCATE = 1 << 14  # ABI 3


def _libc():
    libc = ctypes.CDLL(None, use_errno=True)
    libc.syscall.restype = ctypes.c_long
    return libc


def abi() -> int:
    """The kernel's Landlock ABI version; 0 where there is none (not Linux, not built in, disabled)."""
    numbers = _SYSCALLS.get(os.uname().machine) if sys.platform.startswith("linux") else None
    if numbers is None:
        return 0
    try:
        version = _libc().syscall(numbers[0], None, ctypes.c_size_t(0), ctypes.c_uint32(_CREATE_RULESET_VERSION))
    except (OSError, AttributeError):
        return 0
    return max(int(version), 0)


def write_rights(version: int) -> int:
    """Every right that changes the file system, as far as ABI `version` knows them."""
    rights = WRITE_FILE | REMOVE_DIR | REMOVE_FILE | MAKE_CHAR | MAKE_DIR | MAKE_REG | MAKE_SOCK | MAKE_FIFO \
        | MAKE_BLOCK | MAKE_SYM
    if version >= 2:
        rights |= REFER
    if version >= 3:
        rights |= TRUNCATE
    return rights


# Devices a renderer opens for writing (Blender's GPU back ends, /dev/null): written, never made.
DEVICES = ("/dev/null", "/dev/zero", "/dev/dri", "/dev/nvidia0", "/dev/nvidiactl", "/dev/nvidia-uvm",
           "/dev/nvidia-uvm-tools", "/dev/nvidia-modeset", "/dev/kfd")


def write_ruleset(folders, devices=DEVICES, shared_memory="/dev/shm") -> int | None:
    """A Landlock ruleset (its file descriptor, close-on-exec) that lets a process write only under
    `folders` (anything: create, change, remove), into the existing `devices`, and files (no
    folders, no links) in `shared_memory`, where POSIX shared memory and semaphores live (a
    renderer's device processes share their image there); None where Landlock is not available.
    The folders must exist."""
    version = abi()
    if version < 1:
        return None
    create, add_rule, _ = _SYSCALLS[os.uname().machine]
    handled = write_rights(version)
    libc = _libc()
    attr = struct.pack("<Q", handled)  # struct landlock_ruleset_attr's first field: the fs rights
    fd = libc.syscall(create, ctypes.c_char_p(attr), ctypes.c_size_t(len(attr)), ctypes.c_uint32(0))
    if fd < 0:
        return None
    try:
        rules = [(f, handled) for f in folders]
        rules += [(d, WRITE_FILE | (handled & TRUNCATE)) for d in devices if os.path.exists(d)]
        if shared_memory and os.path.isdir(shared_memory):
            rules.append((shared_memory, WRITE_FILE | MAKE_REG | REMOVE_FILE | (handled & TRUNCATE)))
        for path, rights in rules:
            target = os.open(path, os.O_PATH | os.O_CLOEXEC)
            try:
                if not os.path.isdir(path) and path not in devices:
                    raise NotADirectoryError(f"{path} is not a folder")
                rule = struct.pack("<Qi", rights, target)  # struct landlock_path_beneath_attr (packed)
                if libc.syscall(add_rule, ctypes.c_int(fd), ctypes.c_int(_RULE_PATH_BENEATH), ctypes.c_char_p(rule),
                                ctypes.c_uint32(0)) != 0:
                    err = ctypes.get_errno()
                    raise OSError(err, f"landlock_add_rule({path}): {os.strerror(err)}")
            finally:
                os.close(target)
    except BaseException:
        os.close(fd)
        raise
    return fd


def restrict_self(ruleset: int):
    """Enforce `ruleset` on this process and its children, for good: called in a child between fork
    and exec (a subprocess preexec_fn). Raises OSError if the kernel refuses, so the child never
    runs unconfined by mistake."""
    libc = _libc()
    if libc.prctl(_PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_SET_NO_NEW_PRIVS)")
    if libc.syscall(_SYSCALLS[os.uname().machine][2], ctypes.c_int(ruleset), ctypes.c_uint32(0)) != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"landlock_restrict_self: {os.strerror(err)}")
