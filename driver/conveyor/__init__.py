"""The conveyor: its Modbus link, register map and config file, the exposure clock that
dates frames against belt readings, the conveyor log beside a capture, and reject rules."""
