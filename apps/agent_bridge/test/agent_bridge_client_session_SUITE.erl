%% The client's pure session (agent_bridge_client_session) replayed through
%% the shared transcripts of test/vectors (README.md there, section 5.5),
%% without a node or a socket: for each entity of a transcript, the
%% server's frames are fed to the session as it reads them, its client
%% steps are asked of it as the API would (Hello on a connection, describe,
%% send, request, GetBinding, the Ack timer), and every frame the session
%% writes must be the recorded one byte for byte, in order, and nothing
%% else. What it passes to its owner (signals, Binding reports, the
%% feedback to request/3, reconnected, accepted) is checked against what
%% the transcript says it received, each once.
%%
%% A connection replaced by a later one of the same entity (the version 2
%% resume) is lost right after the client's last step on it: what the
%% server sent on it after that was never read (so the Resume's Received
%% is the recorded 1, and the SensorData comes again on the new
%% connection).
-module(agent_bridge_client_session_SUITE).

-include_lib("common_test/include/ct.hrl").

-export([all/0, suite/0, init_per_suite/1, end_per_suite/1]).
-export([transcript_v1/1, transcript_v2/1, transcript_requests/1,
         a_changed_frame_is_caught/1]).

-define(V, agent_bridge_vectors).
-define(S, agent_bridge_client_session).
-define(EP, {{127, 0, 0, 1}, 7400}).

suite() -> [{timetrap, {minutes, 1}}].

all() ->
    [transcript_v1, transcript_v2, transcript_requests, a_changed_frame_is_caught].

init_per_suite(Config) ->
    Dir = ?V:vectors_dir(),
    {ok, Json} = file:read_file(filename:join(Dir, "vectors.json")),
    {ok, #{<<"vectors">> := Vectors}} = evatar_json:decode(Json, #{max_size => 16#1000000}),
    Transcripts = maps:from_list([{Name, V} || #{<<"kind">> := <<"transcript">>,
                                                 <<"name">> := Name} = V <- Vectors]),
    [{dir, Dir}, {transcripts, Transcripts} | Config].

end_per_suite(_Config) ->
    ok.

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% Version 1: VA and Avatar join, describe, request, Progress, Feedback
%% (the request's answer), sensor data.
transcript_v1(Config) ->
    #{<<"agent">> := Agent, <<"avatar">> := Avatar} = replay(Config, <<"transcript_v1">>),
    [{binding, _}, {binding, _}, {signal, #{context := progress}},
     {reply, {ok, #{context := feedback}}}, {signal, #{context := sensor_data}}] = Agent,
    %% The last Binding report: the VA has left.
    [{binding, _}, {signal, #{context := request}}, {binding, #{entities := [<<"7008">>]}}] =
        Avatar,
    ok.

%% Version 2: Ack Accepted, Ack Received from the Ack timer, a resume on a
%% second connection after which the unacknowledged SensorData comes
%% again and is passed once.
transcript_v2(Config) ->
    #{<<"agent">> := Agent} = replay(Config, <<"transcript_v2">>),
    [{binding, _}, {binding, _}, {accepted, [<<"va-1-000001">>]},
     {reply, {ok, #{context := feedback}}},
     {reconnected, #{resumed := true, epoch := 1, reason := closed}},
     {binding, _}, {signal, #{context := sensor_data, seq := 2}}] = Agent,
    ok.

%% GetBinding, and EVATAR's own Timeout feedback answering the request.
transcript_requests(Config) ->
    #{<<"agent">> := Agent, <<"avatar">> := Avatar} = replay(Config, <<"transcript_requests">>),
    [{binding, _}, {binding, _}, {reply, {ok, #{context := feedback, sender := <<"EVATAR">>}}}] =
        Agent,
    [{binding, _}, {binding, _}, {signal, #{context := request}}, {signal, #{context := event}},
     {signal, #{context := error}}, {binding, #{entities := [<<"7008">>]}}] = Avatar,
    ok.

%% The replay can fail: a recorded client frame the session would write
%% otherwise is caught.
a_changed_frame_is_caught(Config) ->
    #{<<"steps">> := Steps} = T = maps:get(<<"transcript_v2">>, ?config(transcripts, Config)),
    Changed = [case S of
                   #{<<"from">> := <<"client">>, <<"expect">> := #{<<"control">> := <<"Hello">>}} ->
                       S#{<<"expect">> := (maps:get(<<"expect">>, S))#{<<"credential">> := <<"x">>}};
                   _ -> S
               end || S <- Steps],
    {'EXIT', {{frame_differs, _, _}, _}} =
        (catch replay_steps(Config, T#{<<"steps">> := Changed})),
    ok.

%% ---------------------------------------------------------------------------
%% The replay
%% ---------------------------------------------------------------------------

replay(Config, Name) ->
    replay_steps(Config, maps:get(Name, ?config(transcripts, Config))).

%% Returns, per entity, what its owner and callers were given, in order.
replay_steps(Config, #{<<"steps">> := Steps0}) ->
    Steps = lists:zip(lists:seq(1, length(Steps0)), Steps0),
    Unread = unread(Steps),
    Final = lists:foldl(fun({I, Step}, Acc) ->
                                case lists:member(I, Unread) of
                                    true -> Acc;
                                    false -> step(Config, I, Step, Acc)
                                end
                        end, #{}, Steps),
    maps:map(fun(_, #{given := Given, sent := []}) -> lists:reverse(Given) end, Final).

%% The server steps on a replaced connection after the client's last step
%% on it.
unread(Steps) ->
    Entities = lists:usort([entity(C) || {_, #{<<"connection">> := C}} <- Steps]),
    lists:append(
      [begin
           Conns = lists:usort([C || {_, #{<<"connection">> := C}} <- Steps, entity(C) =:= E]),
           [I || C <- Conns, C =/= lists:last(Conns),
                 Last <- [lists:max([J || {J, #{<<"from">> := <<"client">>,
                                            <<"connection">> := C1}} <- Steps, C1 =:= C])],
                 {I, #{<<"connection">> := C2}} <- Steps, C2 =:= C, I > Last]
       end || E <- Entities]).

entity(Conn) ->
    hd(binary:split(Conn, <<"_resumed">>)).

step(Config, I, #{<<"from">> := From, <<"connection">> := Conn, <<"file">> := File,
                  <<"expect">> := Expect}, Acc) ->
    Entity = entity(Conn),
    Doc = ?V:body(read(Config, File)),
    E0 = maps:get(Entity, Acc, #{conn => undefined, session => undefined, given => [],
                                 sent => [], requests => #{}}),
    E1 = case From of
             <<"client">> -> client(I, Conn, Expect, E0);
             <<"server">> -> server(I, Expect, E0)
         end,
    E2 = case From of
             <<"client">> -> expect_sent(Doc, E1);
             <<"server">> -> E1
         end,
    case E2 of
        #{sent := [Extra | _]} -> error({unexpected_frame, I, Extra});
        _ -> Acc#{Entity => E2}
    end.

%% What the client's API (or its Ack timer) asks of the session for a
%% recorded client frame.
client(I, Conn, #{<<"control">> := Root} = Hello, #{conn := Old} = E)
  when Root =:= <<"Hello">>; Root =:= <<"Resume">> ->
    S0 = case E of
             #{session := undefined} ->
                 {control, {_, H}} = ?V:from_json(Hello),
                 Opts = #{pairing => maps:get(pairing, H), role => maps:get(role, H),
                          entity_id => maps:get(entity_id, H),
                          credential => maps:get(credential, H),
                          ha => maps:get(protocol_version, H) =:= 2, notify_acks => true},
                 ?S:new([?EP], Opts, <<"N">>);
             #{session := S} when Old =/= Conn ->
                 %% A later connection: the one before is lost.
                 {reconnect, _, S1} = ?S:lost(closed, I, S),
                 S1
         end,
    {connect, ?EP, S2} = ?S:next_attempt(I, S0),
    E#{conn := Conn, session := S2, sent := [?S:hello(S2)]};
client(_I, _Conn, #{<<"control">> := <<"Bye">>}, #{session := S} = E) ->
    %% close/1: the process writes the Bye; nobody is left waiting.
    {[], S1} = ?S:finish(S),
    E#{session := S1, sent := [bil_control:encode({bye, <<>>})], conn := closed};
client(_I, _Conn, #{<<"control">> := <<"Ack">>}, #{session := S} = E) ->
    effects(?S:ack_due(S), E);
client(_I, _Conn, #{<<"control">> := <<"GetBinding">>}, #{session := S} = E) ->
    effects({?S:get_binding(caller, S), S}, E);
client(I, _Conn, Json, #{session := S, requests := R} = E) ->
    case ?V:from_json(Json) of
        {description, D} ->
            effects(?S:describe(caller, bil:encode_description(D), S), E);
        {signal, #{context := request, id := Id, timestamp := Ts} = Sig} ->
            effects(?S:request({request, Id}, Sig, 10000, Ts, S), E#{requests := R#{Id => I}});
        {signal, #{timestamp := Ts} = Sig} ->
            effects(?S:send(caller, Sig, Ts, S), E)
    end.

%% A frame read on the entity's live connection.
server(_I, _Json, #{conn := closed} = E) ->
    %% After close/1's Bye the process reads only for the server's Bye.
    E;
server(I, Json, #{session := S} = E) ->
    case ?V:from_json(Json) of
        {control, {welcome, W}} ->
            {ok, Effects, S1} = ?S:welcomed(W, I, S),
            effects({Effects, S1}, E);
        Doc ->
            {ok, Effects, S1} = ?S:incoming({ok, Doc}, I, S),
            effects({Effects, S1}, E)
    end.

%% Frames written are compared with the recording; replies to the
%% request's caller and notifications to the owner are kept; replies to
%% the other calls must be `ok'.
effects({Effects, S}, #{sent := Sent, given := Given} = E) ->
    {Sent1, Given1} =
        lists:foldl(
          fun({send, F}, {Fs, Gs}) -> {Fs ++ [F], Gs};
             ({send, F, {reply, caller}}, {Fs, Gs}) -> {Fs ++ [F], Gs};
             ({send, F, {request, _}}, {Fs, Gs}) -> {Fs ++ [F], Gs};
             ({reply, caller, ok}, Acc) -> Acc;
             ({reply, {request, _}, Reply}, {Fs, Gs}) -> {Fs, [{reply, Reply} | Gs]};
             ({notify, Event}, {Fs, Gs}) -> {Fs, [Event | Gs]};
             ({timer, _, _}, Acc) -> Acc;
             ({cancel, _}, Acc) -> Acc
          end, {Sent, Given}, Effects),
    E#{session := S, sent := Sent1, given := Given1}.

expect_sent(Doc, #{sent := [F | Rest]} = E) ->
    case iolist_to_binary(F) of
        Doc -> E#{sent := Rest};
        Other -> error({frame_differs, Other, Doc})
    end;
expect_sent(Doc, #{sent := []}) ->
    error({frame_not_written, Doc}).

read(Config, Rel) ->
    {ok, Bin} = file:read_file(filename:join(?config(dir, Config), binary_to_list(Rel))),
    Bin.
