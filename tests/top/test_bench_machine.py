"""The CPU a measurement ran on, as ``companion bench`` and ``benchmarks/`` name it."""

from __future__ import annotations

from companion.bench.machine import cpu_model, machine_line

# The first processor's block of a KVM guest's /proc/cpuinfo: the name alone says only "AMD EPYC".
KVM_GUEST = ("processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 26\nmodel\t\t: 2\n"
             "model name\t: AMD EPYC\n\nprocessor\t: 1\nvendor_id\t: AuthenticAMD\ncpu family\t: 25\n"
             "model\t\t: 1\nmodel name\t: another CPU\n")


def test_a_bare_model_name_keeps_the_family_and_model_numbers_of_the_first_cpu(tmp_path):
    info = tmp_path / "cpuinfo"
    info.write_text(KVM_GUEST)
    assert cpu_model(info) == "AMD EPYC (family 26, model 2)"


def test_without_proc_cpuinfo_the_platform_still_names_something(tmp_path):
    name = cpu_model(tmp_path / "absent")
    assert name and "family" not in name


def test_the_benchmark_header_names_the_cpu_and_the_core_count():
    line = machine_line()
    assert line.startswith(f"machine: {cpu_model()}, ")
    assert "logical CPUs" in line and "Python 3." in line
