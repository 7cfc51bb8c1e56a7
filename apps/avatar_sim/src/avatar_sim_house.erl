%% @doc Internal. The "easy" smart home of the paper (3.2, Table 1) as a pure
%% model run by {@link avatar_sim_world}: rooms, the devices of
%% smart_home.xml (cameras with motion detection and photos, RF light and
%% socket switches, microphone, notifier, time sensor, speaker, door keypad)
%% and scripted people whose moves, words and key presses the devices
%% perceive. Requests and signals are as docs/avatars.md section 4 says.
-module(avatar_sim_house).
-behaviour(avatar_sim_world).

-export([init/2, tick/2, request/3, bound/4, command/3, state/2]).

-record(h, {comps :: #{binary() => map()},
            people = #{} :: #{binary() => #{room := binary(), moving := boolean()}},
            lights = #{} :: #{binary() => on | off},
            light_log = [] :: [map()],
            played = [] :: [map()],
            emails = [] :: [map()],
            sms = [] :: [map()],
            photos = [] :: [map()],
            photo_bytes = #{} :: #{binary() => binary()},
            keypad = [] :: [map()],
            listening = true :: boolean(),
            attempts = 0 :: non_neg_integer(),
            last_input = none :: none | right | wrong,
            last_input_time = never :: never | integer(),
            motion = #{} :: #{binary() => map()},
            script = [] :: [avatar_sim_script:checked()],
            last_step :: integer(),
            tasks = [] :: [{integer(), non_neg_integer(), term()}],
            seq = 0 :: non_neg_integer(),
            files = 0 :: non_neg_integer(),
            start :: integer(),
            now :: integer(),
            next_time :: integer(),
            next_midnight :: integer(),
            cfg :: map()}).

-define(DAY, 86400000).

%% ---------------------------------------------------------------------------
%% Model callbacks
%% ---------------------------------------------------------------------------

-spec init(map(), integer()) -> #h{}.
init(Opts, Now) ->
    Desc = maps:get(description, Opts),
    Comps = components(Desc),
    Location = maps:merge(#{lat => 51.5074, lon => -0.1278, utc_offset => 0},
                          maps:get(location, Opts, #{})),
    Cfg = #{spool => maps:get(spool, Opts),
            password => maps:get(password, Opts, <<"1234">>),
            email_to => maps:get(email_to, Opts, <<"resident@home.example">>),
            email_from => maps:get(email_from, Opts, <<"evatar-home@home.example">>),
            location => Location,
            time_period => maps:get(time_period, Opts, 60000),
            motion_repeat => maps:get(motion_repeat, Opts, 30000),
            motion_quiet => maps:get(motion_quiet, Opts, 30000)},
    Lights = maps:from_list([{Room, off} || #{kind := K, room := Room} <- maps:values(Comps),
                                            K =:= light orelse K =:= socket]),
    Motion = maps:from_list([{Room, #{reported => false, last => never, next => 0}}
                             || #{kind := motion, room := Room} <- maps:values(Comps)]),
    People = maps:map(fun(_, Room) -> #{room => Room, moving => true} end,
                      maps:get(people, Opts, #{})),
    Period = maps:get(time_period, Cfg),
    #h{comps = Comps, lights = Lights, motion = Motion, people = People,
       script = maps:get(script, Opts, []), last_step = Now, start = Now, now = Now,
       next_time = (Now div Period + 1) * Period,
       next_midnight = next_midnight(Now, Location), cfg = Cfg}.

%% What each component is, from its first service and its Room parameter.
components(#{components := Cs}) ->
    maps:from_list([{Id, component(C)} || #{id := Id} = C <- Cs]).

component(#{services := [#{type := Type, parameters := P} | _], consumes := Consumes}) ->
    Kind = case keyword(Type) of
               <<"readmotion">> -> motion;
               <<"takephoto">> -> camera;
               <<"turnlighton">> -> light;
               <<"turnlightoff">> -> light;
               <<"switchsocketon">> -> socket;
               <<"switchsocketoff">> -> socket;
               <<"listenforcommands">> -> microphone;
               <<"sendemail">> -> notifier;
               <<"sendsms">> -> notifier;
               <<"readtime">> -> time;
               <<"playsound">> -> speaker;
               <<"playvoicemessage">> -> speaker;
               <<"readkeypad">> -> keypad;
               _ -> unknown
           end,
    Feedback = [Cat || #{category := Cat, type := T} <- Consumes,
                       keyword(T) =:= <<"actionfeedback">>],
    Body = case {Feedback, Consumes} of
               {[Cat | _], _} -> {Cat, <<"ACTION FEEDBACK">>};
               {[], [#{category := Cat, type := T} | _]} -> {Cat, T};
               {[], []} -> {<<"SENSOR">>, Type}
           end,
    #{kind => Kind, room => proplists:get_value(<<"Room">>, P, <<"hall">>), body => Body,
      pushes => maps:from_list([{keyword(T), T} || #{type := T} <- Consumes])}.

-spec tick(integer(), #h{}) -> {#h{}, [avatar_sim_world:effect()]}.
tick(Now, H0) ->
    H = H0#h{now = Now},
    {H1, E1} = run_script(H),
    {H2, E2} = run_tasks(H1),
    {H3, E3} = motion(H2),
    {H4, E4} = time_signals(H3),
    {H4, E1 ++ E2 ++ E3 ++ E4}.

-spec request(bil:signal(), integer(), #h{}) -> {#h{}, [avatar_sim_world:effect()]}.
request(#{receiver := Id, body := #{type := Type, parameters := P}} = Req, Now, H0) ->
    H = H0#h{now = Now},
    case H#h.comps of
        #{Id := #{kind := Kind} = C} ->
            handle(Kind, keyword(Type), C, Req, P, H);
        #{} ->
            {H, []}
    end.

-spec bound(binary(), binary(), integer(), #h{}) -> {#h{}, [avatar_sim_world:effect()]}.
bound(Id, Type, Now, H0) ->
    H = H0#h{now = Now},
    case {maps:get(Id, H#h.comps, undefined), keyword(Type)} of
        {#{kind := time}, <<"timeofday">>} -> {H, [time_push(Id, H)]};
        {#{kind := time}, <<"sunset">>} -> {H, [sunset_push(Id, H)]};
        _ -> {H, []}
    end.

-spec command(term(), integer(), #h{}) -> {term(), #h{}, [avatar_sim_world:effect()]}.
command({act, Who, Action}, Now, H) ->
    case avatar_sim_script:check([{{delay, 0}, Who, Action}]) of
        {ok, _} ->
            {H1, Es} = act(Who, Action, H#h{now = Now}),
            {ok, H1, Es};
        {error, {script, _, Why}} ->
            {{error, Why}, H, []}
    end;
command(_Other, _Now, H) ->
    {{error, unknown_command}, H, []}.

-spec state(integer(), #h{}) -> map().
state(Now, H) ->
    #{time => Now, local_time => local_datetime(Now, H),
      people => H#h.people, lights => H#h.lights,
      light_log => lists:reverse(H#h.light_log), played => lists:reverse(H#h.played),
      emails => lists:reverse(H#h.emails), sms => lists:reverse(H#h.sms),
      photos => lists:reverse(H#h.photos), keypad => lists:reverse(H#h.keypad),
      listening => H#h.listening, script_left => length(H#h.script),
      tasks_left => length(H#h.tasks),
      spool => maps:get(spool, H#h.cfg),
      %% For the dashboard's floor plan: each room's devices, its last motion.
      rooms => lists:foldl(fun(#{kind := K, room := R}, Acc) ->
                                   Acc#{R => lists:usort([K | maps:get(R, Acc, [])])}
                           end, #{}, maps:values(H#h.comps)),
      motion => maps:map(fun(_, #{last := Last}) -> Last end, H#h.motion),
      attempts => H#h.attempts}.

%% ---------------------------------------------------------------------------
%% Requests
%% ---------------------------------------------------------------------------

handle(motion, <<"readmotion">>, #{room := Room}, Req, _P, H) ->
    #{last := Last} = maps:get(Room, H#h.motion),
    {H, [answer(Req, [{<<"Motion">>, moving_in(Room, H) > 0}, {<<"Room">>, Room},
                      {<<"LastMotion">>, case Last of
                                            never -> <<"never">>;
                                            T -> clock(T, H)
                                        end}], H)]};
handle(camera, <<"takephoto">>, #{room := Room}, Req, P, H) ->
    case {avatar_sim_param:number(<<"Count">>, P, 1),
          avatar_sim_param:number(<<"Interval">>, P, 1000)} of
        {{ok, Count}, {ok, Interval}} when Count >= 1, Count =< 10, Interval >= 0 ->
            {H1, Photo, Es} = take_photo(Room, H),
            burst(Req, Room, round(Count), round(Interval), [Photo], Es, H1);
        {{ok, _}, {ok, _}} ->
            {H, [error_answer(Req, <<"BadParameter">>,
                              <<"Count must be 1 to 10 and Interval not negative">>)]};
        {{error, Why}, _} -> {H, [error_answer(Req, <<"BadParameter">>, Why)]};
        {_, {error, Why}} -> {H, [error_answer(Req, <<"BadParameter">>, Why)]}
    end;
handle(light, <<"turnlighton">>, C, Req, _P, H) -> switch(C, on, <<"Light">>, Req, H);
handle(light, <<"turnlightoff">>, C, Req, _P, H) -> switch(C, off, <<"Light">>, Req, H);
handle(socket, <<"switchsocketon">>, C, Req, _P, H) -> switch(C, on, <<"Socket">>, Req, H);
handle(socket, <<"switchsocketoff">>, C, Req, _P, H) -> switch(C, off, <<"Socket">>, Req, H);
handle(microphone, <<"listenforcommands">>, _C, Req, P, H) ->
    case avatar_sim_param:yes_no(<<"Listen">>, P, true) of
        {ok, On} -> {H#h{listening = On}, [answer(Req, [{<<"Listening">>, On}], H)]};
        {error, Why} -> {H, [error_answer(Req, <<"BadParameter">>, Why)]}
    end;
handle(notifier, <<"sendemail">>, _C, Req, P, H) ->
    send_email(Req, P, H);
handle(notifier, <<"sendsms">>, _C, Req, P, H) ->
    send_sms(Req, P, H);
handle(time, <<"readtime">>, _C, Req, _P, H) ->
    {Date, Seconds} = local(H#h.now, H),
    {Rise, Set} = avatar_sim_sun:times(Date, location(H)),
    {H, [answer(Req, [{<<"Date">>, date_text(Date)},
                      {<<"TimeOfDay">>, avatar_sim_param:hhmm(Seconds)},
                      {<<"Seconds">>, Seconds},
                      {<<"Sunrise">>, avatar_sim_param:hhmm(Rise)},
                      {<<"Sunset">>, avatar_sim_param:hhmm(Set)},
                      {<<"Dark">>, Seconds < Rise orelse Seconds >= Set},
                      {<<"Epoch">>, H#h.now}], H)]};
handle(speaker, <<"playsound">>, _C, Req, P, H) ->
    case {avatar_sim_param:number(<<"Volume">>, P, 80),
          avatar_sim_param:number(<<"Duration">>, P, 3000)} of
        {{ok, Volume}, {ok, Duration}} when Duration >= 0 ->
            Sound = avatar_sim_param:text(<<"Sound">>, P, <<"alarm">>),
            play(Req, sound, Sound, round(Volume), round(Duration), H);
        {{ok, _}, {ok, _}} -> {H, [error_answer(Req, <<"BadParameter">>,
                                                <<"Duration must not be negative">>)]};
        {{error, Why}, _} -> {H, [error_answer(Req, <<"BadParameter">>, Why)]};
        {_, {error, Why}} -> {H, [error_answer(Req, <<"BadParameter">>, Why)]}
    end;
handle(speaker, <<"playvoicemessage">>, _C, Req, P, H) ->
    case avatar_sim_param:number(<<"Volume">>, P, 80) of
        {ok, Volume} ->
            Message = avatar_sim_param:text(<<"Message">>, P, <<>>),
            play(Req, voice, Message, round(Volume), 60 * string:length(Message), H);
        {error, Why} ->
            {H, [error_answer(Req, <<"BadParameter">>, Why)]}
    end;
handle(keypad, <<"readkeypad">>, _C, Req, _P, H) ->
    {H, [answer(Req, [{<<"Attempts">>, H#h.attempts}, {<<"LastInput">>, H#h.last_input},
                      {<<"LastTime">>, case H#h.last_input_time of
                                           never -> <<"never">>;
                                           T -> clock(T, H)
                                       end}], H)]};
handle(_Kind, _Type, _C, #{receiver := Id, body := #{type := Type}} = Req, _P, H) ->
    {H, [error_answer(Req, <<"UnknownService">>,
                      <<Id/binary, " does not provide '", Type/binary, "'">>)]}.

switch(#{room := Room}, On, Name, Req, H) ->
    Changed = maps:get(Room, H#h.lights, off) =/= On,
    H1 = case Changed of
             true -> H#h{lights = (H#h.lights)#{Room => On},
                         light_log = [#{time => H#h.now, room => Room, state => On}
                                      | H#h.light_log]};
             false -> H
         end,
    {H1, [answer(Req, [{Name, On}, {<<"Room">>, Room}, {<<"Changed">>, Changed}], H1)]}.

take_photo(Room, H) ->
    N = H#h.files + 1,
    Id = list_to_binary(io_lib:format("photo-~4..0B.png", [N])),
    People = lists:sort([Who || {Who, #{room := R}} <- maps:to_list(H#h.people), R =:= Room]),
    Lit = maps:get(Room, H#h.lights, off) =:= on orelse not dark(H),
    Png = avatar_sim_png:photo(Room, Lit, People, H#h.now),
    File = filename:join([maps:get(spool, H#h.cfg), "photos", Id]),
    Photo = #{id => Id, file => unicode:characters_to_binary(File), room => Room,
              time => H#h.now, people => People},
    {H#h{files = N, photos = [Photo | H#h.photos],
         photo_bytes = (H#h.photo_bytes)#{Id => Png}},
     Id, [{file, File, Png}]}.

%% The remaining photos of a burst are tasks on the clock; one progress per
%% photo but the last, and the feedback names them all.
burst(Req, Room, Count, _Interval, Taken, Es, H) when length(Taken) >= Count ->
    Ids = lists:reverse(Taken),
    {H, Es ++ [answer(Req, [{<<"Photos">>, join(Ids)}, {<<"Count">>, length(Ids)},
                            {<<"Room">>, Room}], H)]};
burst(Req, Room, Count, Interval, [Last | _] = Taken, Es, H) ->
    Progress = answer(Req, [{<<"Photo">>, Last}, {<<"Taken">>, length(Taken)},
                            {<<"Room">>, Room}], progress, H),
    {schedule(H#h.now + Interval, {burst, Req, Room, Count, Interval, Taken}, H),
     Es ++ [Progress]}.

play(Req, Kind, What, Volume, Duration, H) ->
    Entry = #{time => H#h.now, kind => Kind, what => What, volume => Volume},
    H1 = H#h{played = [Entry | H#h.played]},
    Params = [{<<"Played">>, What}, {<<"Volume">>, Volume}, {<<"Duration">>, Duration}],
    {schedule(H#h.now + Duration, {answer, Req, Params}, H1), []}.

send_email(Req, P, H) ->
    Ids = avatar_sim_param:list(<<"Attachment">>, P),
    case [Id || Id <- Ids, not maps:is_key(Id, H#h.photo_bytes)] of
        [] ->
            Cfg = H#h.cfg,
            N = H#h.files + 1,
            File = spool_file(N, ".eml", H),
            MessageId = list_to_binary(io_lib:format("~B.~B@avatar-sim.home.example",
                                                     [H#h.now, N])),
            To = avatar_sim_param:text(<<"To">>, P, maps:get(email_to, Cfg)),
            Subject = avatar_sim_param:text(<<"Subject">>, P, <<"EVATAR home">>),
            Bytes = avatar_sim_mail:email(
                      #{from => maps:get(email_from, Cfg), to => To, subject => Subject,
                        body => avatar_sim_param:text(<<"Body">>, P, <<>>), date => H#h.now,
                        utc_offset => utc_offset(H), message_id => MessageId,
                        attachments => [{Id, <<"image/png">>, maps:get(Id, H#h.photo_bytes)}
                                        || Id <- Ids]}),
            Entry = #{file => File, subject => Subject, to => To, attachments => Ids,
                      time => H#h.now},
            H1 = H#h{files = N, emails = [Entry | H#h.emails]},
            {H1, [{file, File, Bytes},
                  answer(Req, [{<<"File">>, File}, {<<"MessageID">>, MessageId},
                               {<<"Attachments">>, length(Ids)}], H1)]};
        Unknown ->
            {H, [error_answer(Req, <<"UnknownPhoto">>,
                              <<"no photo called ", (join(Unknown))/binary>>)]}
    end.

send_sms(Req, P, H) ->
    N = H#h.files + 1,
    File = spool_file(N, ".sms", H),
    To = avatar_sim_param:text(<<"To">>, P, <<"+440000000000">>),
    Text = avatar_sim_param:text(<<"TextMsg">>, P, <<>>),
    Bytes = avatar_sim_mail:sms(#{to => To, text => Text, date => H#h.now,
                                  utc_offset => utc_offset(H)}),
    H1 = H#h{files = N, sms = [#{file => File, to => To, text => Text, time => H#h.now}
                               | H#h.sms]},
    {H1, [{file, File, Bytes}, answer(Req, [{<<"File">>, File}], H1)]}.

spool_file(N, Ext, H) ->
    {{Y, Mo, D}, {Hh, Mi, S}} = local_datetime(H#h.now, H),
    Name = io_lib:format("~4..0B~2..0B~2..0B-~2..0B~2..0B~2..0B-~B~s",
                         [Y, Mo, D, Hh, Mi, S, N, Ext]),
    unicode:characters_to_binary(filename:join(maps:get(spool, H#h.cfg), Name)).

%% ---------------------------------------------------------------------------
%% People
%% ---------------------------------------------------------------------------

run_script(#h{script = [Step | Rest], now = Now, last_step = Prev, start = Start} = H) ->
    Due = avatar_sim_script:due(Step, Prev, Start, utc_offset(H)),
    case Due =< Now of
        true ->
            {_, Who, Action} = Step,
            {H1, Es} = act(Who, Action, H#h{script = Rest, last_step = Due}),
            {H2, Es2} = run_script(H1),
            {H2, Es ++ Es2};
        false ->
            {H, []}
    end;
run_script(H) ->
    {H, []}.

act(Who, Action, H) ->
    Person = maps:get(Who, H#h.people, #{room => <<"outside">>, moving => true}),
    do(Action, Who, Person, H).

do({go, Room}, Who, Person, H) ->
    {put_person(Who, Person#{room := Room, moving := true}, H), []};
do(still, Who, Person, H) ->
    {put_person(Who, Person#{moving := false}, H), []};
do(moving, Who, Person, H) ->
    {put_person(Who, Person#{moving := true}, H), []};
do({say, Text}, Who, #{room := Room} = Person, H) ->
    H1 = put_person(Who, Person, H),
    Mics = [Id || {Id, #{kind := microphone, room := R}} <- lists:sort(maps:to_list(H#h.comps)),
                  R =:= Room],
    case H#h.listening of
        true -> {H1, [push(Id, event, <<"voicecommand">>,
                           [{<<"Text">>, Text}, {<<"Room">>, Room}, {<<"Format">>, <<"text">>}],
                           H1) || Id <- Mics]};
        false -> {H1, []}
    end;
do({keypad, Code}, Who, #{room := Room} = Person, H) when Room =:= <<"hall">>;
                                                           Room =:= <<"outside">> ->
    H1 = put_person(Who, Person, H),
    Wrong = Code =/= maps:get(password, H#h.cfg),
    Attempts = case Wrong of true -> H#h.attempts + 1; false -> 0 end,
    H2 = H1#h{attempts = Attempts, last_input = case Wrong of true -> wrong; false -> right end,
              last_input_time = H#h.now,
              keypad = [#{time => H#h.now, who => Who, wrong => Wrong} | H#h.keypad]},
    Pads = [{Id, R} || {Id, #{kind := keypad, room := R}} <- lists:sort(maps:to_list(H#h.comps))],
    {H2, [push(Id, event, <<"passwordinput">>,
               [{<<"WrongPassword">>, Wrong}, {<<"Room">>, R}, {<<"Attempts">>, Attempts}], H2)
          || {Id, R} <- Pads]};
do({keypad, _Code}, Who, Person, H) ->
    %% Nobody can reach the keypad from inside the house.
    {put_person(Who, Person, H), []}.

put_person(Who, Person, H) -> H#h{people = (H#h.people)#{Who => Person}}.

moving_in(Room, H) ->
    length([W || {W, #{room := R, moving := true}} <- maps:to_list(H#h.people), R =:= Room]).

%% ---------------------------------------------------------------------------
%% Tick work
%% ---------------------------------------------------------------------------

schedule(Due, Task, #h{tasks = Tasks, seq = Seq} = H) ->
    H#h{tasks = lists:sort([{Due, Seq, Task} | Tasks]), seq = Seq + 1}.

run_tasks(#h{tasks = [{Due, _, Task} | Rest], now = Now} = H) when Due =< Now ->
    {H1, Es} = task(Task, H#h{tasks = Rest}),
    {H2, Es2} = run_tasks(H1),
    {H2, Es ++ Es2};
run_tasks(H) ->
    {H, []}.

task({answer, Req, Params}, H) ->
    {H, [answer(Req, Params, H)]};
task({burst, Req, Room, Count, Interval, Taken}, H) ->
    {H1, Photo, Es} = take_photo(Room, H),
    burst(Req, Room, Count, Interval, [Photo | Taken], Es, H1).

%% Cameras report motion when it starts, again while it goes on, and its
%% end after a quiet period.
motion(#h{motion = Motion, now = Now, cfg = Cfg} = H) ->
    Repeat = maps:get(motion_repeat, Cfg),
    Quiet = maps:get(motion_quiet, Cfg),
    {Motion1, Es} =
        lists:foldl(
          fun({Room, #{reported := Rep, last := Last, next := Next} = S}, {Acc, Es0}) ->
                  N = moving_in(Room, H),
                  {S1, Push} =
                      if N > 0, not Rep -> {S#{reported := true, last := Now, next := Now + Repeat},
                                            [{true, N}]};
                         N > 0, Now >= Next -> {S#{last := Now, next := Next + Repeat},
                                                [{true, N}]};
                         N > 0 -> {S#{last := Now}, []};
                         Rep, Now - Last >= Quiet -> {S#{reported := false}, [{false, 0}]};
                         true -> {S, []}
                      end,
                  {Acc#{Room => S1}, Es0 ++ [motion_push(Room, M, C, H) || {M, C} <- Push]}
          end, {Motion, []}, lists:sort(maps:to_list(Motion))),
    {H#h{motion = Motion1}, lists:append(Es)}.

motion_push(Room, Moving, Count, H) ->
    [push(Id, event, <<"motiondetected">>,
          [{<<"Motion">>, Moving}, {<<"Room">>, Room}, {<<"People">>, Count}], H)
     || {Id, #{kind := motion, room := R}} <- lists:sort(maps:to_list(H#h.comps)), R =:= Room].

time_signals(#h{now = Now, next_time = Next, cfg = Cfg} = H) ->
    Times = [Id || {Id, #{kind := time}} <- lists:sort(maps:to_list(H#h.comps))],
    {H1, E1} = case Now >= Next of
                   true -> {H#h{next_time = Next + maps:get(time_period, Cfg)},
                            [time_push(Id, H) || Id <- Times]};
                   false -> {H, []}
               end,
    case Now >= H1#h.next_midnight of
        true -> {H1#h{next_midnight = next_midnight(Now, location(H1))},
                 E1 ++ [sunset_push(Id, H1) || Id <- Times]};
        false -> {H1, E1}
    end.

time_push(Id, H) ->
    {Date, Seconds} = local(H#h.now, H),
    push(Id, sensor_data, <<"timeofday">>,
         [{<<"Date">>, date_text(Date)}, {<<"TimeOfDay">>, avatar_sim_param:hhmm(Seconds)},
          {<<"Seconds">>, Seconds}, {<<"Dark">>, dark(H)}, {<<"Epoch">>, H#h.now}], H).

sunset_push(Id, H) ->
    {Date, _} = local(H#h.now, H),
    {Rise, Set} = avatar_sim_sun:times(Date, location(H)),
    push(Id, sensor_data, <<"sunset">>,
         [{<<"Date">>, date_text(Date)}, {<<"Sunrise">>, avatar_sim_param:hhmm(Rise)},
          {<<"Sunset">>, avatar_sim_param:hhmm(Set)}], H).

%% ---------------------------------------------------------------------------
%% Signals and time
%% ---------------------------------------------------------------------------

answer(Req, Params, H) -> answer(Req, Params, feedback, H).

answer(#{receiver := Id, body := #{type := Requested}} = Req, Params, Context, H) ->
    #{body := {Cat, Type}} = maps:get(Id, H#h.comps),
    Result = case Context of feedback -> [{<<"Result">>, done}]; progress -> [] end,
    {answer, Req, Context,
     #{category => Cat, type => Type,
       parameters => avatar_sim_param:params([{<<"Service">>, Requested} | Result] ++ Params)}}.

error_answer(Req, Code, Message) ->
    {answer, Req, error, #{category => <<"ERROR">>, type => Code,
                           parameters => [{<<"Message">>, Message}]}}.

%% A push whose type is the component's Consumes entry with that keyword,
%% as written in the description (the bindings are keyed by it).
push(Id, Context, Keyword, Params, H) ->
    #{pushes := Pushes} = maps:get(Id, H#h.comps),
    Type = maps:get(Keyword, Pushes, Keyword),
    {push, Id, Context, #{category => <<"SENSOR">>, type => Type,
                          parameters => avatar_sim_param:params(Params)}}.

location(#h{cfg = #{location := L}}) -> L.
utc_offset(H) -> maps:get(utc_offset, location(H)).

local(Ms, H) ->
    {Date, {Hh, Mi, S}} = local_datetime(Ms, H),
    {Date, Hh * 3600 + Mi * 60 + S}.

local_datetime(Ms, H) ->
    Secs = floor_div(Ms, 1000) + utc_offset(H) * 60
        + calendar:datetime_to_gregorian_seconds({{1970, 1, 1}, {0, 0, 0}}),
    calendar:gregorian_seconds_to_datetime(Secs).

dark(H) ->
    {Date, Seconds} = local(H#h.now, H),
    avatar_sim_sun:is_dark(Date, Seconds, location(H)).

next_midnight(Ms, #{utc_offset := Offset}) ->
    Local = Ms + Offset * 60000,
    Local - floor_mod(Local, ?DAY) + ?DAY - Offset * 60000.

clock(Ms, H) ->
    {_, Seconds} = local(Ms, H),
    avatar_sim_param:hhmmss(Seconds).

date_text({Y, M, D}) -> list_to_binary(io_lib:format("~4..0B-~2..0B-~2..0B", [Y, M, D])).

join(Ids) -> iolist_to_binary(lists:join(<<",">>, Ids)).

floor_div(A, B) -> (A - floor_mod(A, B)) div B.

floor_mod(A, B) ->
    R = A rem B,
    case R < 0 of true -> R + B; false -> R end.

keyword(Bin) -> string:lowercase(<< <<C>> || <<C>> <= Bin, is_alnum(C) >>).

is_alnum(C) -> (C >= $a andalso C =< $z) orelse (C >= $A andalso C =< $Z)
                   orelse (C >= $0 andalso C =< $9).
