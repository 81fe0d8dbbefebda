"""csrc/simd.h, where all of the kernels' ISA-specific code lives, checked operation by operation
on every ISA variant: simd_check.cpp is compiled with each variant's flags from CMakeLists.txt
and run. Variants this CPU executes run directly. Those it cannot are emulated, so that their
code paths are executed here, not only compiled:
  neon    on x86-64, under qemu-aarch64 (Debian's g++-aarch64-linux-gnu and qemu-user);
  avx512  on an x86-64 CPU without it, as the init program of Debian's kernel booted in Bochs'
          Skylake-X model, which has AVX-512 F/CD/DQ/BW/VL (QEMU emulates AVX2 but not
          AVX-512). Needs Debian's bochs, bochs-term, bochsbios, vgabios, isolinux,
          syslinux-common, xorriso and cpio, and the kernel `make x86-64-v4-guest` unpacks.
.ci/run installs all of them. The tolerances are in simd_check.cpp: pow2 within 3e-7 relative,
reciprocal within 2.5e-7 (about 2 ulp), sums within 1e-6, the rest exact."""

from __future__ import annotations

import os
import platform
import re
import shutil
import stat
import subprocess
from pathlib import Path

import pytest

from surgsplat.render import native

ROOT = Path(__file__).resolve().parents[2]
SOURCE = Path(__file__).with_name("simd_check.cpp")
# As CMakeLists.txt compiles the module, besides each variant's own flags.
COMMON_FLAGS = ["-std=c++17", "-O3", "-fno-math-errno"]


def variant_flags() -> dict[str, list[str]]:
    """Each ISA variant's compiler flags, read from CMakeLists.txt (set(SURGSPLAT_FLAGS_<isa>))."""
    text = (ROOT / "CMakeLists.txt").read_text()
    return {isa: flags.split() for isa, flags in
            re.findall(r"set\(SURGSPLAT_FLAGS_(\w+) ([^)]*)\)", text)}


GUEST_KERNEL = ROOT / "build" / "x86-64-v4-guest" / "vmlinuz"
ISOLINUX = (Path("/usr/lib/ISOLINUX/isolinux.bin"),
            Path("/usr/lib/syslinux/modules/bios/ldlinux.c32"))
BOCHS_TOOLS = ("bochs", "script", "xorriso", "cpio", "gcc")


def bochs_missing() -> str | None:
    """Why the AVX-512 check cannot run under Bochs here, or None."""
    for tool in BOCHS_TOOLS:
        if shutil.which(tool) is None:
            return f"the AVX-512 check under Bochs needs {tool}"
    for path in (*ISOLINUX, GUEST_KERNEL):
        if not path.exists():
            return f"the AVX-512 check under Bochs needs {path} (make x86-64-v4-guest)"
    return None


def run_in_bochs(binary: Path, folder: Path) -> str:
    """What a static x86-64 `binary` prints when it runs as the init program's child in Debian's
    kernel, booted from a CD image in Bochs' Skylake-X model; the serial console's text."""
    root, disc = folder / "root", folder / "disc"
    (root / "dev").mkdir(parents=True)
    os.mknod(root / "dev" / "console", 0o600 | stat.S_IFCHR, os.makedev(5, 1))
    subprocess.run(["gcc", "-static", "-O2", str(Path(__file__).with_name("bochs_init.c")),
                    "-o", str(root / "init")], check=True, capture_output=True)
    shutil.copy(binary, root / "check")
    (disc / "isolinux").mkdir(parents=True)
    with open(disc / "initrd.img", "wb") as initrd:
        listing = subprocess.run(["find", "."], cwd=root, capture_output=True, check=True)
        subprocess.run(["cpio", "-o", "-H", "newc", "--quiet"], cwd=root, input=listing.stdout,
                       stdout=initrd, check=True)
    shutil.copy(GUEST_KERNEL, disc / "vmlinuz")
    for path in ISOLINUX:
        shutil.copy(path, disc / "isolinux")
    # Bochs 2.7 reports the standard XSAVE area's size (2688 bytes) as the compacted one (2432):
    # the kernel's consistency check then turns XSAVE, and AVX with it, off, unless the
    # compacted formats are hidden from it.
    (disc / "isolinux" / "isolinux.cfg").write_text(
        "default linux\nprompt 0\nlabel linux\n  kernel /vmlinuz\n  append initrd=/initrd.img "
        "console=ttyS0 quiet panic=0 clearcpuid=xsaves,xsavec\n")
    image = folder / "boot.iso"
    subprocess.run(["xorriso", "-as", "mkisofs", "-quiet", "-o", str(image), "-b",
                    "isolinux/isolinux.bin", "-c", "isolinux/boot.cat", "-no-emul-boot",
                    "-boot-load-size", "4", "-boot-info-table", str(disc)],
                   check=True, capture_output=True)
    serial, config, commands = folder / "serial.txt", folder / "bochsrc", folder / "commands"
    config.write_text(
        "cpu: model=corei7_skylake_x\nmemory: guest=256, host=256\n"
        "romimage: file=/usr/share/bochs/BIOS-bochs-latest\n"
        "vgaromimage: file=/usr/share/bochs/VGABIOS-lgpl-latest\n"
        f"ata0-master: type=cdrom, path={image}, status=inserted\nboot: cdrom\n"
        f"com1: enabled=1, mode=file, dev={serial}\ndisplay_library: term\n"
        f"log: {folder / 'bochs.log'}\nclock: sync=none\nspeaker: enabled=0\n"
        "sound: driver=dummy\n")
    commands.write_text("c\n")  # Debian's Bochs starts in its debugger: continue
    # the terminal display needs a terminal: `script` gives it one
    subprocess.run(["script", "-q", "-c", f"bochs -q -f {config} -rc {commands}", "/dev/null"],
                   env={**os.environ, "TERM": "xterm"}, stdin=subprocess.DEVNULL,
                   capture_output=True, timeout=1500)
    return serial.read_text(errors="replace") if serial.exists() else ""


def build_and_run_command(isa: str, binary: Path, folder: Path) -> tuple[list[str], list[str]]:
    """The compile command of `isa`'s check and the command that runs it (empty: run it in
    Bochs); skips the test when this machine has no way to build or execute that variant."""
    host = platform.machine().lower()
    if isa == "neon" and host not in ("aarch64", "arm64"):
        compiler, runner = shutil.which("aarch64-linux-gnu-g++"), shutil.which("qemu-aarch64")
        if compiler is None or runner is None:
            pytest.skip("the NEON check needs aarch64-linux-gnu-g++ and qemu-aarch64 "
                        "(Debian: g++-aarch64-linux-gnu, qemu-user)")
        return [compiler, "-static"], [runner, str(binary)]
    compiler = shutil.which("g++") or shutil.which("c++")
    if compiler is None:
        pytest.skip("no C++ compiler")
    reason = native.isa_unavailable(isa)
    if reason is None:
        return [compiler], [str(binary)]
    if isa == "avx512" and host in ("x86_64", "amd64"):
        missing = bochs_missing()
        if missing is not None:
            pytest.skip(f"{reason}; {missing}")
        return [compiler, "-static"], []
    pytest.skip(reason)


def test_every_variant_has_flags_in_cmakelists():
    assert set(variant_flags()) == set(native.ISAS)


def emulated_slow(isa: str):
    """`isa` as a parameter, marked slow when this CPU cannot run it (then it runs emulated:
    under qemu, or a kernel booted in Bochs, which takes minutes)."""
    return pytest.param(isa, marks=pytest.mark.slow if native.isa_unavailable(isa) else ())


@pytest.mark.parametrize("isa", [emulated_slow(isa) for isa in native.ISAS])
def test_simd_operations_match_scalar_arithmetic(isa, tmp_path):
    binary = tmp_path / f"simd_check_{isa}"
    compile_prefix, run = build_and_run_command(isa, binary, tmp_path)
    compiled = subprocess.run(
        [*compile_prefix, *COMMON_FLAGS, *variant_flags()[isa], f'-DSIMD_CHECK_ISA="{isa}"',
         f"-I{ROOT / 'csrc'}", str(SOURCE), "-o", str(binary)],
        capture_output=True, text=True, timeout=300)
    assert compiled.returncode == 0, compiled.stderr
    if run:
        result = subprocess.run(run, capture_output=True, text=True, timeout=300)
        assert result.returncode == 0, result.stdout + result.stderr
        output = result.stdout
    else:
        output = run_in_bochs(binary, tmp_path / "bochs")
        assert "check exited with status 0" in output, output[-3000:]
    summaries = [line for line in output.splitlines() if line.startswith(f"{isa}: ")]
    assert summaries and summaries[-1].strip().endswith(" 0 failed"), output[-3000:]
