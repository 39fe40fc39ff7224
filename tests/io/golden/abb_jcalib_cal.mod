MODULE jcalib_cal
    ! Written by jcalib from a calibration result.
    ! result: jcalib 0.1.0, created 2026-11-21T10:00:00Z, input sha256:0123456789abcdef0123456789abcdef0123456789abcdef0123456789abcdef
    ! reprojection RMS: 0.2143 px
    ! Positions in mm, orientations as quaternions [q1, q2, q3, q4] = [w, x, y, z].

    ! tool_gripper: T_flange_gripper, the TCP in the tool0 (flange) frame.
    ! orientation: calibrated.
    ! Load: default 1 kg at the TCP (not calibrated); identify the real load before use.
    PERS tooldata tool_gripper := [TRUE, [[105.000, -2.100, 133.300], [0.707107, 0.000000, 0.707107, 0.000000]], [1.000, [105.000, -2.100, 133.300], [1, 0, 0, 0], 0.000, 0.000, 0.000]];

    ! tool_needle: T_flange_needle, the TCP in the tool0 (flange) frame.
    ! orientation: calibrated.
    ! 1-sigma TCP position std x/y/z (tool0 frame): 0.070/0.067/0.070 mm.
    ! Load: default 1 kg at the TCP (not calibrated); identify the real load before use.
    PERS tooldata tool_needle := [TRUE, [[12.300, -4.500, 201.500], [0.957887, 0.072123, -0.252195, 0.116830]], [1.000, [12.300, -4.500, 201.500], [1, 0, 0, 0], 0.000, 0.000, 0.000]];

    ! wobj_board: T_base_board, the user frame in the robot base (= world) frame.
    ! 1-sigma origin position std x/y/z (base frame): 0.025/0.034/0.030 mm.
    PERS wobjdata wobj_board := [FALSE, TRUE, "", [[900.000, -120.000, 10.000], [0.004780, -0.923860, -0.382642, 0.006703]], [[0, 0, 0], [1, 0, 0, 0]]];
ENDMODULE
