MODULE JcalibStop
  !=================================================================================================
  ! jcalib stop task for ABB IRC5 / OmniCore: the STOP path of robot/abb/PROTOCOL.md (version 2).
  ! JcalibServer.mod waits for the robot while it moves, so it cannot read a stop request; this module
  ! runs in a second task (Type NORMAL or SEMISTATIC, no motion: "MotionTask" No) and listens on
  ! jc_stop_port. Each connection carries one request:
  !   STOP -> increments jc_stop_seq; JcalibServer's interrupt on it brakes the robot on its path
  !           (StopMove, ClearPath) and its move request is answered ERR 6 STOPPED.
  !           Reply "OK STOPPED" when a motion was in progress (jc_moving), else "OK IDLE".
  !   PING -> "OK JCALIB 2".
  ! then the task closes the connection. Needs the "Socket Messaging" option (PC Interface on RW6) and,
  ! for a second task, "Multitasking". Untested on a physical controller: try it in manual reduced
  ! speed first; the teach pendant's stop and the emergency stop stay the primary means of stopping.
  !=================================================================================================
  CONST num JC_VERSION := 2;
  ! Shared with JcalibServer (same names and types in both tasks).
  PERS string jc_ip := "192.168.125.1";
  PERS num jc_stop_port := 5516;
  PERS num jc_stop_seq := 0;
  PERS bool jc_moving := FALSE;

  VAR socketdev stop_srv;
  VAR socketdev stop_cli;

  PROC main()
    SocketClose stop_srv;
    SocketCreate stop_srv;
    SocketBind stop_srv, jc_ip, jc_stop_port;
    SocketListen stop_srv;
    WHILE TRUE DO
      SocketAccept stop_srv, stop_cli \Time:=WAIT_MAX;
      ServeOne;
      SocketClose stop_cli;
    ENDWHILE
  ENDPROC

  ! Read one request line, answer it.
  PROC ServeOne()
    VAR string req := "";
    VAR string word := "";
    SocketReceive stop_cli \Str:=req \Time:=2;
    IF StrLen(req) >= 4 word := StrPart(req, 1, 4);
    IF word = "STOP" THEN
      ! also counts while no motion runs yet: a move whose request is being handled checks jc_stop_seq
      jc_stop_seq := jc_stop_seq + 1;
      IF jc_moving THEN
        SocketSend stop_cli \Str:="OK STOPPED\0A";
      ELSE
        SocketSend stop_cli \Str:="OK IDLE\0A";
      ENDIF
    ELSEIF word = "PING" THEN
      SocketSend stop_cli \Str:="OK JCALIB " + NumToStr(JC_VERSION, 0) + "\0A";
    ELSE
      SocketSend stop_cli \Str:="ERR 5 UNKNOWN\0A";
    ENDIF
  ERROR
    ! a client that sent nothing within 2 s, or went away: main closes it and waits for the next one
    IF ERRNO = ERR_SOCK_TIMEOUT OR ERRNO = ERR_SOCK_CLOSED THEN
      RETURN;
    ENDIF
  ENDPROC
ENDMODULE
