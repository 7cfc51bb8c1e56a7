// The smart-home holiday policy (holiday.asl, docs/rules.md) as a spade-bdi agent
// embodied through EVATAR (evatar.spade): the same schedule and intruder, but each
// request is the action .act, which suspends the plan until the device answers and
// fails (the event +failed(Component, Service, Reason)) when it cannot.
//
// Percepts: reading(Component, Type, Params, Time), bound(Component),
// unbound(Component, Service, Reason), failed(Component, Service, Reason).
// Actions: .act(Component, Service, Params[, Feedback]), .minute, .log.

// The schedule: at HH:MM, room, on/off, under which condition.
schedule("18:00", living, on, dark).
schedule("19:10", kitchen, on, dark).
schedule("19:40", kitchen, off, dark).
schedule("20:30", bedroom, on, dark).
schedule("20:30", living, off, dark).
schedule("22:00", all, off, always).

// The VA's light emulators (smart_home_va.xml): room, emulator, on, off.
light("living", living, "LivingLightEmulator01", "TurnLightOn", "TurnLightOff").
light("kitchen", kitchen, "KitchenLightEmulator01", "TurnLightOn", "TurnLightOff").
light("bedroom", bedroom, "LampEmulator01", "SwitchSocketOn", "SwitchSocketOff").

// Motion and a failed authorisation within this many ms of the house's clock
// (2 min), unless a right code was typed in between; not again within the window.
window(120000).

// ---------------------------------------------------------------- the clock

+reading(_, "TimeOfDay", Ps, _)
    : .member(p("TimeOfDay", T), Ps) & .member(p("Dark", D), Ps) <-
    .minute(T, M);
    !tick(M, D).

+!tick(M, D) : now(L) & M > L <-
    -+now(M);
    for (schedule(At, Room, State, Cond)) {
        .minute(At, A);
        if (A > L & A <= M & (Cond == always | D == "yes")) {
            .log("policy holiday at ", At, " do light ", Room, " ", State);
            !switch(Room, State)
        }
    }.
+!tick(M, _) : now(_) <- -+now(M).
+!tick(M, _) <- +now(M).

+!switch(all, State) <-
    for (light(_, Room, _, _, _)) { !switch(Room, State) }.
+!switch(Room, on) : light(_, Room, E, On, _) <- .act(E, On, [], Ps); !switched(Room, on, Ps).
+!switch(Room, off) : light(_, Room, E, _, Off) <- .act(E, Off, [], Ps); !switched(Room, off, Ps).

+!switched(Room, State, Ps) : .member(p("Changed", C), Ps) <-
    .log("light ", Room, " ", State, " (changed ", C, ")").
+!switched(_, _, _).

// ------------------------------------------------------------- the intruder

+reading(_, "PasswordInput", Ps, T) : .member(p("WrongPassword", "yes"), Ps) <-
    .log("activity failed_authorisation in hall");
    +failed_authorisation(T);
    !recognise(T).
+reading(_, "PasswordInput", Ps, T) : .member(p("WrongPassword", "no"), Ps) <-
    +authorisation(T).
+reading(_, "MotionDetected", Ps, T)
    : .member(p("Motion", "yes"), Ps) & .member(p("Room", Room), Ps) <-
    +motion(T, Room);
    !recognise(T).

+!recognise(T)
    : window(W) & failed_authorisation(F) & F <= T & T - F <= W
      & motion(M, Room) & M <= T & T - M <= W
      & not (authorisation(A) & A >= F)
      & not (intruder(I) & T - I < W) <-
    +intruder(T);
    .log("complex activity intruder in ", Room);
    !respond(Room).
+!recognise(_).

// policy holiday on intruder do photos 3, email "INTRUSION" with photos,
// alarm, say "You are being recorded. The police have been called."
+!respond(Room) <-
    .log("policy holiday on intruder do photos 3");
    .act("CameraEmulator01", "TakePhoto", [p("Count", 3), p("Interval", 1000)], Ps);
    !report(Ps).

+!report(Ps) : .member(p("Photos", Ids), Ps) <-
    .log("camera: photos ", Ids);
    .act("NotifierEmulator01", "SendEmail",
         [p("Subject", "INTRUSION"),
          p("Body", "INTRUSION: intruder in the hall, photos attached"),
          p("Attachment", Ids)], Mail);
    !mailed(Mail);
    !alarm.
+!report(_) <- !alarm.

+!mailed(Mail) : .member(p("File", F), Mail) <- .log("e-mail written to ", F).
+!mailed(_).

+!alarm <-
    .act("SpeakerEmulator01", "PlaySound", [p("Sound", "alarm"), p("Volume", 100)]);
    .log("alarm sounded");
    !say.
+!say <-
    .act("SpeakerEmulator01", "PlayVoiceMessage",
         [p("Message", "You are being recorded. The police have been called."),
          p("Volume", 100)]);
    .log("warning spoken").

// A failed action ends its plan; these go on from where it stopped.
+failed(Component, Service, Reason) <- .log("failed ", Component, " ", Service, ": ", Reason); !recover(Service).
+!recover("TakePhoto") <- !alarm.
+!recover("SendEmail") <- !alarm.
+!recover("PlaySound") <- !say.
+!recover(_).
