MODULE tending
  ! golden test
  PERS tooldata tGripper := [TRUE,[[0,0,150],[1,0,0,0]],[1,[0,0,75],[1,0,0,0],0,0,0]];
  CONST speeddata vJoint := [1000,500,5000,1000];
  CONST speeddata vLine100 := [100,500,5000,1000];
  CONST speeddata vLine250 := [250,500,5000,1000];
  CONST zonedata zBlend10 := [FALSE,10,10,10,1,10,1];
  CONST zonedata zBlend20 := [FALSE,20,20,20,2,20,2];
  CONST zonedata zBlend5 := [FALSE,5,5,5,0.5,5,0.5];
  CONST jointtarget j1 := [[0,-90.0002,90.0002,-90.0002,-90.0002,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];
  CONST robtarget p1 := [[450,-120,300],[0,1,0,0],[0,0,0,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];
  CONST robtarget p2 := [[450,-120,400],[0.007146,-0.995446,0,-0.095058],[0,0,0,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];
  CONST jointtarget j2 := [[28.6479,-68.7549,80.2141,-97.4028,-90.0002,14.3239],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];
  CONST jointtarget j3 := [[31.5127,-65.8901,77.3493,-97.4028,-90.0002,17.1887],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];
  CONST jointtarget j4 := [[34.3775,-63.0254,74.4845,-97.4028,-90.0002,20.0535],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];

  PROC main()
    ConfJ\Off;
    ConfL\Off;
    MoveAbsJ j1\NoEOffs, vJoint, fine, tGripper;
    ! load: approach stock
    MoveL p1, vLine100, fine, tGripper;
    ! grip
    SetDO do0, 1;
    WaitTime 0.4;
    MoveL p2, vLine250, zBlend10, tGripper;
    MoveAbsJ j2\NoEOffs, vJoint, zBlend20, tGripper;
    MoveAbsJ j3\NoEOffs, vJoint\T:=0.25, zBlend5, tGripper;
    MoveAbsJ j4\NoEOffs, vJoint\T:=0.25, fine, tGripper;
    WaitTime 1.5;
    SetDO do0, 0;
    SetDO do3, 1;
  ENDPROC
ENDMODULE
