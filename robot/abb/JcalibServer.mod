MODULE JcalibServer
  !=================================================================================================
  ! jcalib socket server for ABB IRC5 / OmniCore (RobotWare 6 / 7): lets a PC move the robot to
  ! calibration stations and read its pose. Protocol: robot/abb/PROTOCOL.md (one line per message,
  ! at most 80 bytes with the LF). Needs the "Socket Messaging" option (PC Interface on RW6).
  ! Load it into a motion task, set jc_ip / jc_port, and run main in AUTO with motors on.
  ! STOP requests arrive on a second port, served by JcalibStop.mod in a second (non-motion) task,
  ! because this task is busy waiting for the robot while it moves; the two share jc_stop_seq and
  ! jc_moving (PERS variables of the same name are shared between tasks).
  ! Untested on a physical controller: try it in manual reduced speed first.
  !=================================================================================================
  CONST num JC_VERSION := 2;
  PERS string jc_ip := "192.168.125.1";     ! controller address the server listens on
  PERS num jc_port := 5515;
  PERS num jc_stop_port := 5516;            ! JcalibStop listens there (announced by PING)

  ! Shared with the JcalibStop task: it increments jc_stop_seq on every STOP and reads jc_moving.
  PERS num jc_stop_seq := 0;
  PERS bool jc_moving := FALSE;
  VAR intnum jc_stop_int;
  VAR num jc_seq0;                          ! jc_stop_seq when the move request arrived

  ! Tools / work objects selectable with TOOL n / WOBJ n (0 = tool0 / wobj0). Edit to your cell.
  PERS tooldata jc_tools{4} := [
    [TRUE,[[0,0,100],[1,0,0,0]],[1,[0,0,50],[1,0,0,0],0,0,0]],
    [TRUE,[[0,0,100],[1,0,0,0]],[1,[0,0,50],[1,0,0,0],0,0,0]],
    [TRUE,[[0,0,100],[1,0,0,0]],[1,[0,0,50],[1,0,0,0],0,0,0]],
    [TRUE,[[0,0,100],[1,0,0,0]],[1,[0,0,50],[1,0,0,0],0,0,0]]];
  PERS wobjdata jc_wobjs{4} := [
    [FALSE,TRUE,"",[[0,0,0],[1,0,0,0]],[[0,0,0],[1,0,0,0]]],
    [FALSE,TRUE,"",[[0,0,0],[1,0,0,0]],[[0,0,0],[1,0,0,0]]],
    [FALSE,TRUE,"",[[0,0,0],[1,0,0,0]],[[0,0,0],[1,0,0,0]]],
    [FALSE,TRUE,"",[[0,0,0],[1,0,0,0]],[[0,0,0],[1,0,0,0]]]];

  ! Active tool / work object (motion instructions need PERS arguments).
  PERS tooldata jc_tool := [TRUE,[[0,0,0],[1,0,0,0]],[0.001,[0,0,0.001],[1,0,0,0],0,0,0]];
  PERS wobjdata jc_wobj := [FALSE,TRUE,"",[[0,0,0],[1,0,0,0]],[[0,0,0],[1,0,0,0]]];

  VAR speeddata jc_speed := [200,100,5000,1000];   ! SPEED v sets v_tcp (mm/s)
  VAR num jc_settle := 0.2;                        ! SETTLE s: dwell after every move (s)

  VAR socketdev srv;
  VAR socketdev cli;
  VAR bool connected := FALSE;
  VAR bool reach_ok := TRUE;
  VAR bool motion_ok := TRUE;
  VAR string buf := "";

  PROC main()
    jc_tool := tool0;
    jc_wobj := wobj0;
    ConfJ \Off;
    ConfL \Off;
    SingArea \Wrist;
    jc_moving := FALSE;
    IDelete jc_stop_int;
    CONNECT jc_stop_int WITH JcStopTrap;
    IPers jc_stop_seq, jc_stop_int;          ! interrupt on every change of jc_stop_seq
    SocketClose srv;
    SocketCreate srv;
    SocketBind srv, jc_ip, jc_port;
    SocketListen srv;
    WHILE TRUE DO
      SocketAccept srv, cli \Time:=WAIT_MAX;
      connected := TRUE;
      buf := "";
      Serve;
      SocketClose cli;
    ENDWHILE
  ENDPROC

  ! Serve one client until it says BYE or disconnects.
  PROC Serve()
    VAR string chunk;
    VAR string line;
    VAR num p;
    WHILE connected DO
      SocketReceive cli \Str:=chunk \Time:=WAIT_MAX;
      IF connected THEN
        IF StrLen(buf) + StrLen(chunk) > 80 THEN
          buf := "";
          Reply "ERR 1 SYNTAX";
        ELSE
          buf := buf + chunk;
        ENDIF
        p := StrFind(buf, 1, "\0A");
        WHILE connected AND p <= StrLen(buf) DO
          line := StrPart(buf, 1, p - 1);
          IF p < StrLen(buf) THEN
            buf := StrPart(buf, p + 1, StrLen(buf) - p);
          ELSE
            buf := "";
          ENDIF
          Handle line;
          p := StrFind(buf, 1, "\0A");
        ENDWHILE
      ENDIF
    ENDWHILE
  ERROR
    IF ERRNO = ERR_SOCK_CLOSED OR ERRNO = ERR_SOCK_TIMEOUT THEN
      connected := FALSE;
      TRYNEXT;
    ENDIF
  ENDPROC

  PROC Reply(string text)
    SocketSend cli \Str:=text + "\0A";
  ERROR
    IF ERRNO = ERR_SOCK_CLOSED THEN
      connected := FALSE;
      TRYNEXT;
    ENDIF
  ENDPROC

  ! Next blank-separated token of s (removed from s); "" when none is left.
  FUNC string NextTok(INOUT string s)
    VAR num p;
    VAR string t;
    VAR bool more := TRUE;
    WHILE more DO
      more := FALSE;
      IF StrLen(s) > 0 THEN
        IF StrPart(s, 1, 1) = " " OR StrPart(s, 1, 1) = "\0D" THEN
          s := StrPart(s, 2, StrLen(s) - 1);
          more := TRUE;
        ENDIF
      ENDIF
    ENDWHILE
    IF StrLen(s) = 0 RETURN "";
    p := StrFind(s, 1, " \0D");
    t := StrPart(s, 1, p - 1);
    IF p > StrLen(s) THEN
      s := "";
    ELSE
      s := StrPart(s, p + 1, StrLen(s) - p);
    ENDIF
    RETURN t;
  ENDFUNC

  ! Parse exactly n numbers from s into v{1..n}; FALSE on any syntax error or extra token.
  FUNC bool Numbers(INOUT string s, num n, INOUT num v{*})
    VAR string t;
    FOR i FROM 1 TO n DO
      t := NextTok(s);
      IF t = "" RETURN FALSE;
      IF NOT StrToVal(t, v{i}) RETURN FALSE;
    ENDFOR
    RETURN NextTok(s) = "";
  ENDFUNC

  PROC Handle(string line)
    VAR string rest;
    VAR string cmd;
    VAR num v{7};
    VAR robtarget p;
    VAR jointtarget j;
    rest := line;
    cmd := NextTok(rest);
    TEST cmd
    CASE "PING":
      Reply "OK JCALIB " + NumToStr(JC_VERSION, 0) + " " + NumToStr(jc_stop_port, 0);
    CASE "BYE":
      Reply "OK";
      connected := FALSE;
    CASE "GETP":
      p := CRobT(\Tool:=jc_tool \WObj:=jc_wobj);
      Reply "POSE " + NumToStr(p.trans.x, 3) + " " + NumToStr(p.trans.y, 3) + " " + NumToStr(p.trans.z, 3)
        + " " + NumToStr(p.rot.q1, 6) + " " + NumToStr(p.rot.q2, 6) + " " + NumToStr(p.rot.q3, 6)
        + " " + NumToStr(p.rot.q4, 6);
    CASE "GETJ":
      j := CJointT();
      Reply "JNT " + NumToStr(j.robax.rax_1, 3) + " " + NumToStr(j.robax.rax_2, 3) + " "
        + NumToStr(j.robax.rax_3, 3) + " " + NumToStr(j.robax.rax_4, 3) + " "
        + NumToStr(j.robax.rax_5, 3) + " " + NumToStr(j.robax.rax_6, 3);
    CASE "MOVJ", "MOVL":
      IF NOT Numbers(rest, 7, v) THEN
        Reply "ERR 1 SYNTAX";
      ELSE
        DoMove cmd = "MOVL", v;
      ENDIF
    CASE "TOOL", "WOBJ", "SPEED", "SETTLE":
      IF NOT Numbers(rest, 1, v) THEN
        Reply "ERR 1 SYNTAX";
      ELSE
        SetParam cmd, v{1};
      ENDIF
    DEFAULT:
      Reply "ERR 5 UNKNOWN";
    ENDTEST
  ENDPROC

  PROC SetParam(string cmd, num x)
    IF cmd = "TOOL" OR cmd = "WOBJ" THEN
      IF x <> Round(x) OR x < 0 OR x > 4 THEN
        Reply "ERR 3 RANGE";
        RETURN;
      ENDIF
      IF cmd = "TOOL" THEN
        IF x = 0 THEN
          jc_tool := tool0;
        ELSE
          jc_tool := jc_tools{x};
        ENDIF
      ELSE
        IF x = 0 THEN
          jc_wobj := wobj0;
        ELSE
          jc_wobj := jc_wobjs{x};
        ENDIF
      ENDIF
    ELSEIF cmd = "SPEED" THEN
      IF x < 1 OR x > 2000 THEN
        Reply "ERR 3 RANGE";
        RETURN;
      ENDIF
      jc_speed.v_tcp := x;
    ELSE
      IF x < 0 OR x > 10 THEN
        Reply "ERR 3 RANGE";
        RETURN;
      ENDIF
      jc_settle := x;
    ENDIF
    Reply "OK";
  ENDPROC

  ! Interrupt on jc_stop_seq (a STOP from JcalibStop): brake on the path, stand, drop the rest of the
  ! path. DoMove sees the changed jc_stop_seq once WaitRob returns and answers ERR 6 STOPPED.
  TRAP JcStopTrap
    IF jc_moving THEN
      StopMove;                 ! ramp down on the path (not an emergency stop)
      WaitRob \ZeroSpeed;
      ClearPath;                ! the interrupted MoveJ / MoveL does not resume
      StartMove;
    ENDIF
  ENDTRAP

  ! Move the active tool to v = [x y z (mm) q1 q2 q3 q4] in the active work object.
  PROC DoMove(bool linear, num v{*})
    VAR robtarget cur;
    VAR robtarget tgt;
    VAR jointtarget jt;
    jc_seq0 := jc_stop_seq;
    cur := CRobT(\Tool:=jc_tool \WObj:=jc_wobj);
    tgt := cur;
    tgt.trans := [v{1}, v{2}, v{3}];
    tgt.rot := NOrient([v{4}, v{5}, v{6}, v{7}]);
    reach_ok := TRUE;
    motion_ok := TRUE;
    jt := CalcJointT(tgt, jc_tool \WObj:=jc_wobj);   ! controller's own reach / joint limit check
    IF NOT reach_ok THEN
      Reply "ERR 2 UNREACHABLE";
      RETURN;
    ENDIF
    jc_moving := TRUE;
    ! \Conc: the program goes on while the robot moves, so that a stop can clear the path and
    ! WaitRob below returns at the fine point or wherever the robot stopped.
    IF linear THEN
      MoveL \Conc, tgt, jc_speed, fine, jc_tool \WObj:=jc_wobj;
    ELSE
      MoveJ \Conc, tgt, jc_speed, fine, jc_tool \WObj:=jc_wobj;
    ENDIF
    IF jc_stop_seq <> jc_seq0 THEN   ! a STOP arrived before the motion was on the path
      StopMove;
      WaitRob \ZeroSpeed;
      ClearPath;
      StartMove;
    ENDIF
    WaitRob \InPos;
    jc_moving := FALSE;
    IF jc_stop_seq <> jc_seq0 THEN
      Reply "ERR 6 STOPPED";
      RETURN;
    ENDIF
    IF NOT motion_ok THEN
      Reply "ERR 4 MOTION";
      RETURN;
    ENDIF
    WaitTime jc_settle;
    Reply "OK";
  ERROR
    IF ERRNO = ERR_ROBLIMIT OR ERRNO = ERR_OUTSIDE_REACH THEN
      reach_ok := FALSE;
      SkipWarn;
      TRYNEXT;
    ENDIF
    motion_ok := FALSE;
    SkipWarn;
    TRYNEXT;
  ENDPROC
ENDMODULE
