"""What tests and benchmarks need from the host they run on (stdlib and numpy only).

:mod:`.multihost`: two network namespaces joined by a veth pair (two hosts on one machine,
needs root) and the Fast DDS profile that makes discovery and data cross that link;
:mod:`.stall_witness`: a witness of the machine's own stalls, to tell a slow node from a
stalled machine.
"""
