"""The D1 spec's example strings with the typed values they mean, byte for byte, both ways:
the golden tables of the codec's tests, and seeds of the fuzz targets."""

from __future__ import annotations

from fleet.d1 import protocol as p

GOLDEN_COMMANDS: list[tuple[str, p.Command]] = [
    (
        '{"seq":4,"address":1,"funcode":1,"data":{"id":5,"angle":60,"delay_ms":0}}',
        p.SetJointAngle(joint=5, angle_deg=60.0, delay_ms=0),
    ),
    (
        '{"seq":4,"address":1,"funcode":2,"data":{"mode":1,"angle0":0,"angle1":-60,"angle2":60,'
        '"angle3":0,"angle4":30,"angle5":0,"angle6":0}}',
        p.SetAllAngles(angles_deg=(0.0, -60.0, 60.0, 0.0, 30.0, 0.0, 0.0), mode=1),
    ),
    (
        '{"seq":4,"address":1,"funcode":4,"data":{"id":5,"mode":1}}',
        p.SetJointTorque(joint=5, enable=True),
    ),
    ('{"seq":4,"address":1,"funcode":5,"data":{"mode":0}}', p.SetAllTorque(mode=0)),
    ('{"seq":4,"address":1,"funcode":6,"data":{"power":1}}', p.SetPower(on=True)),
    ('{"seq":4,"address":1,"funcode":7}', p.ReturnToZero()),
]

GOLDEN_MESSAGES: list[tuple[str, p.ArmMessage]] = [
    (
        '{"seq":10,"address":2,"funcode":1,"data":{"angle0":0,"angle1":-60,"angle2":60,'
        '"angle3":0,"angle4":30,"angle5":0,"angle6":0}}',
        p.JointAngles(angles_deg=(0.0, -60.0, 60.0, 0.0, 30.0, 0.0, 0.0)),
    ),
    (
        '{"seq":10,"address":2,"funcode":3,"data":{"enable_status":1,"power_status":1,'
        '"error_status":1}}',
        p.D1Status(enabled=True, powered=True, error_status=1),
    ),
    (
        '{"seq":10,"address":2,"funcode":4,"data":{"motor0_status":1,"motor1_status":1,'
        '"motor2_status":1,"motor3_status":1,"motor4_status":1,"motor5_status":1,'
        '"motor6_status":1}}',
        p.MotorStatus(motors_ok=(True,) * 7),
    ),
    # The spec's ack examples carry seq 10; an ack echoes the seq of the command it answers.
    ('{"seq":10,"address":3,"funcode":1,"data":{"recv_status":1}}', p.ReceiveAck(10, True)),
    ('{"seq":10,"address":3,"funcode":2,"data":{"exec_status":1}}', p.ExecuteAck(10, True)),
]
