%% The client session's decisions one by one, without a process or a
%% socket: the endpoint ring, the window of unacknowledged signals,
%% de-duplication, request correlation, heartbeats and the resume.
%% agent_bridge_client_session_SUITE replays the shared vectors through it.
-module(agent_bridge_client_session_tests).

-include_lib("eunit/include/eunit.hrl").

-define(S, agent_bridge_client_session).
-define(A, {{127, 0, 0, 1}, 1}).
-define(B, {{127, 0, 0, 1}, 2}).
-define(C, {{127, 0, 0, 1}, 3}).

opts(Ha) ->
    #{pairing => <<"p">>, role => agent, entity_id => <<"va">>, credential => <<"c">>,
      ha => Ha, notify_acks => true, reconnect_backoff => {20, 80},
      reconnect_limit => 1000}.

new(Ha) -> ?S:new([?A, ?B, ?C], opts(Ha), <<"N">>).

welcome(Window) ->
    welcome(Window, false, <<>>).

welcome(Window, Resumed, Last) ->
    #{pairing => <<"p">>, entity_id => <<"va">>, session_id => <<"SID">>, join_timeout => 5000,
      max_frame => 1048576,
      ha => #{epoch => 3, resumed => Resumed, last_accepted => Last, dedup_window => Window,
              heartbeat => 100}}.

%% A version 2 session welcomed at time 0.
up(Window) ->
    {connect, ?A, S0} = ?S:next_attempt(0, new(true)),
    {ok, _, S1} = ?S:welcomed(welcome(Window), 0, S0),
    S1.

signal(Id) ->
    #{id => Id, sender => <<"s">>, receiver => <<"r">>,
      body => #{category => <<"C">>, type => <<"T">>, parameters => []}}.

delivered(Seq, Epoch) ->
    (signal(<<"in-", (integer_to_binary(Seq))/binary>>))#{
      context => sensor_data, in_reply_to => undefined, timestamp => 1, seq => Seq,
      epoch => Epoch}.

binding(Ids) -> {ok, {control, {binding, #{entities => Ids, bound => [], unbound => []}}}}.

sends(Effects) -> [iolist_to_binary(F) || {send, F} <- Effects].
replies(Effects) -> [{F, R} || {reply, F, R} <- Effects].
notes(Effects) -> [E || {notify, E} <- Effects].

parse(Frame) ->
    {ok, Term} = bil_control:parse_frame(iolist_to_binary(Frame), #{}),
    Term.

%% ---------------------------------------------------------------------------
%% The endpoint ring
%% ---------------------------------------------------------------------------

v1_tries_each_endpoint_once_test() ->
    {connect, ?A, S1} = ?S:next_attempt(0, new(false)),
    {now, S2} = ?S:attempt_failed(econnrefused, 0, S1),
    {connect, ?B, S3} = ?S:next_attempt(0, S2),
    {now, S4} = ?S:attempt_failed(timeout, 0, S3),
    {connect, ?C, S5} = ?S:next_attempt(0, S4),
    {now, S6} = ?S:attempt_failed(closed, 0, S5),
    ?assertEqual({give_up, {unreachable, [{?A, econnrefused}, {?B, timeout}, {?C, closed}]}},
                 ?S:next_attempt(0, S6)).

v2_goes_round_with_doubling_pauses_test() ->
    {connect, ?A, S1} = ?S:next_attempt(0, new(true)),
    {now, S2} = ?S:attempt_failed(closed, 0, S1),
    {connect, ?B, S3} = ?S:next_attempt(0, S2),
    {now, S4} = ?S:attempt_failed(closed, 0, S3),
    {connect, ?C, S5} = ?S:next_attempt(0, S4),
    %% A full round: pause at least the minimum, doubling, at most the maximum.
    {{retry, 20}, S6} = ?S:attempt_failed(closed, 0, S5),
    {connect, ?A, S7} = ?S:next_attempt(10, S6),
    {now, S8} = ?S:attempt_failed(closed, 0, S7),
    {connect, ?B, S9} = ?S:next_attempt(10, S8),
    {now, S10} = ?S:attempt_failed(closed, 0, S9),
    {connect, ?C, S11} = ?S:next_attempt(10, S10),
    {{retry, 40}, S12} = ?S:attempt_failed(closed, 0, S11),
    Pauses = lists:foldl(fun(_, {Ps, S}) ->
                                 {connect, _, Sa} = ?S:next_attempt(10, S),
                                 case ?S:attempt_failed(closed, 0, Sa) of
                                     {{retry, P}, Sb} -> {[P | Ps], Sb};
                                     {now, Sb} -> {Ps, Sb}
                                 end
                         end, {[], S12}, lists:seq(1, 9)),
    ?assertEqual([80, 80, 80], lists:reverse(element(1, Pauses))),
    %% Never welcomed: past the limit the failures are the answer.
    {give_up, {unreachable, [{?A, closed} | _]}} = ?S:next_attempt(1001, element(2, Pauses)).

v2_starts_after_the_lost_endpoint_and_gives_up_after_the_limit_test() ->
    {connect, ?A, S0} = ?S:next_attempt(0, new(true)),
    {connect, ?B, S1} = ?S:next_attempt(0, element(2, ?S:attempt_failed(closed, 0, S0))),
    {ok, _, S2} = ?S:welcomed(welcome(8), 0, S1),
    {reconnect, _, S3} = ?S:lost(closed, 500, S2),
    {connect, ?C, S4} = ?S:next_attempt(500, S3),
    {now, S5} = ?S:attempt_failed(econnrefused, 500, S4),
    {connect, ?A, S6} = ?S:next_attempt(1400, S5),
    {now, S7} = ?S:attempt_failed(econnrefused, 1400, S6),
    ?assertEqual({give_up, {gave_up, econnrefused}}, ?S:next_attempt(1501, S7)).

%% A crowd of clients resuming at once on a node too busy to answer all in
%% time: each handshake given up in a row doubles the next one's wait (up
%% to 8 times handshake_timeout), so the node's late answers stop being
%% work for clients that left; refusals in between do not reset it, a
%% Welcome does.
handshake_wait_grows_while_handshakes_time_out_test() ->
    S0 = ?S:new([?A, ?B, ?C], (opts(true))#{handshake_timeout => 1000}, <<"N">>),
    ?assertEqual(5000, ?S:handshake_timeout(new(true))),
    ?assertEqual(1000, ?S:handshake_timeout(S0)),
    {connect, ?A, S1} = ?S:next_attempt(0, S0),
    {now, S2} = ?S:attempt_failed(handshake_timeout, 0, S1),
    ?assertEqual(2000, ?S:handshake_timeout(S2)),
    {connect, ?B, S3} = ?S:next_attempt(0, S2),
    {now, S4} = ?S:attempt_failed({refused, <<"NotActive">>, <<>>}, 0, S3),
    ?assertEqual(2000, ?S:handshake_timeout(S4)),
    Slow = lists:foldl(fun(_, S) ->
                               {connect, _, Sa} = ?S:next_attempt(0, S),
                               element(2, ?S:attempt_failed(handshake_timeout, 0, Sa))
                       end, S4, lists:seq(1, 5)),
    ?assertEqual(8000, ?S:handshake_timeout(Slow)),
    {connect, _, S5} = ?S:next_attempt(0, Slow),
    {ok, _, Up} = ?S:welcomed(welcome(8), 0, S5),
    ?assertEqual(1000, ?S:handshake_timeout(Up)),
    {reconnect, _, Lost} = ?S:lost(server_silent, 1, Up),
    ?assertEqual(1000, ?S:handshake_timeout(Lost)),
    ?assertEqual(infinity, ?S:handshake_timeout(
                             ?S:new([?A], (opts(true))#{handshake_timeout => infinity}, <<"N">>))).

refusals_test() ->
    ?assertEqual(retry, ?S:refused_in_handshake(<<"NotActive">>, <<>>, new(true))),
    ?assertEqual(retry, ?S:refused_in_handshake(<<"SessionResumed">>, <<>>, new(true))),
    ?assertEqual(final, ?S:refused_in_handshake(<<"BadCredential">>, <<>>, new(true))),
    ?assertEqual(final, ?S:refused_in_handshake(<<"NotActive">>, <<>>, new(false))),
    S = up(8),
    ?assertMatch({reconnect, _, _}, ?S:lost({refused, <<"Fenced">>, <<>>}, 1, S)),
    ?assertMatch({reconnect, _, _}, ?S:lost(server_silent, 1, S)),
    ?assertMatch({reconnect, _, _}, ?S:lost({bye, <<"x">>}, 1, S)),
    ?assertEqual(stop, ?S:lost({refused, <<"BadCredential">>, <<>>}, 1, S)),
    ?assertEqual(stop, ?S:lost({malformed, truncated}, 1, S)),
    {connect, ?A, V1} = ?S:next_attempt(0, new(false)),
    {ok, [], V1Up} = ?S:welcomed(maps:remove(ha, welcome(8)), 0, V1),
    ?assertEqual(stop, ?S:lost(closed, 1, V1Up)).

v2_needs_a_version_2_welcome_test() ->
    {connect, ?A, S} = ?S:next_attempt(0, new(true)),
    ?assertMatch({error, {refused, <<"BadHandshake">>, _}},
                 ?S:welcomed(maps:remove(ha, welcome(8)), 0, S)).

%% ---------------------------------------------------------------------------
%% The window of unacknowledged signals
%% ---------------------------------------------------------------------------

window_blocks_until_acknowledged_test() ->
    S0 = up(2),
    {E1, S1} = ?S:send(f1, signal(<<"a">>), 1, S0),
    {E2, S2} = ?S:send(f2, signal(<<"b">>), 1, S1),
    {E3, S3} = ?S:send(f3, signal(<<"c">>), 1, S2),
    ?assertEqual([{f1, ok}], replies(E1)),
    ?assertEqual([{f2, ok}], replies(E2)),
    %% The window is full: the third waits, unsent and unanswered.
    ?assertEqual({[], []}, {replies(E3), sends(E3)}),
    {Ew, S4} = ?S:await_acks(w, S3),
    ?assertEqual([], replies(Ew)),
    ?assertEqual(3, maps:get(unacked, ?S:status(true, S4)) + 1),
    Ack = fun(Id, S) -> ?S:incoming({ok, {control, {ack, #{accepted => Id}}}}, 2, S) end,
    {ok, E5, S5} = Ack(<<"b">>, S4),
    ?assertEqual([{accepted, [<<"a">>, <<"b">>]}], notes(E5)),
    [Sent] = sends(E5),
    ?assertMatch({signal, #{id := <<"c">>}}, parse(Sent)),
    ?assertEqual([{f3, ok}], replies(E5)),
    %% An Ack for what is no longer waiting changes nothing.
    ?assertMatch({ok, [], _}, Ack(<<"a">>, S5)),
    {ok, E6, S6} = Ack(<<"c">>, S5),
    ?assertEqual([{accepted, [<<"c">>]}], notes(E6)),
    ?assertEqual([{w, ok}], replies(E6)),
    ?assertEqual(0, maps:get(unacked, ?S:status(true, S6))).

not_connected_signals_wait_and_go_on_welcome_test() ->
    {connect, ?A, S0} = ?S:next_attempt(0, new(true)),
    {E1, S1} = ?S:send(f1, signal(<<"a">>), 1, S0),
    ?assertEqual({[{f1, ok}], []}, {replies(E1), sends(E1)}),
    {ok, E2, _} = ?S:welcomed(welcome(8), 0, S1),
    ?assertMatch([{signal, #{id := <<"a">>}}], [parse(F) || F <- sends(E2)]).

bad_signal_is_the_callers_error_test() ->
    S = up(8),
    {E1, S} = ?S:send(f, #{sender => <<"s">>}, 1, S),
    ?assertMatch([{f, {error, {bad_signal, _}}}], replies(E1)),
    {E2, S} = ?S:request(f, not_a_map, 100, 1, S),
    ?assertMatch([{f, {error, {bad_signal, {not_a_map, not_a_map}}}}], replies(E2)).

%% ---------------------------------------------------------------------------
%% De-duplication and acknowledgements
%% ---------------------------------------------------------------------------

nothing_is_passed_twice_test() ->
    S0 = up(8),
    In = fun(Sig, S) -> ?S:incoming({ok, {signal, Sig}}, 1, S) end,
    {ok, E1, S1} = In(delivered(1, 3), S0),
    ?assertEqual([{signal, delivered(1, 3)}], notes(E1)),
    ?assertEqual([{timer, ack, 5}], [E || {timer, _, _} = E <- E1]),
    {ok, E2, S2} = In(delivered(1, 3), S1),
    ?assertEqual([], E2),
    %% An older epoch than one seen: a deposed active's late delivery.
    {ok, E3, S3} = In(delivered(2, 2), S2),
    ?assertEqual([], E3),
    {ok, E4, S4} = In(delivered(2, 4), S3),
    ?assertEqual([{signal, delivered(2, 4)}], notes(E4)),
    ?assertEqual([], [T || {timer, _, _} = T <- E4]),
    {E5, S5} = ?S:ack_due(S4),
    ?assertEqual([{ack, #{received => 2}}], [C || {control, C} <- [parse(F) || F <- sends(E5)]]),
    %% Nothing new: no second Ack.
    ?assertEqual({[], S5}, ?S:ack_due(S5)),
    ?assertMatch(#{last_seq := 2, epoch := 4}, ?S:status(true, S5)).

ack_every_32_at_once_test() ->
    S0 = up(8),
    {Acks, _} = lists:foldl(
                  fun(Seq, {Acc, S}) ->
                          {ok, E, S1} = ?S:incoming({ok, {signal, delivered(Seq, 3)}}, 1, S),
                          {Acc ++ [C || {control, C} <- [parse(F) || F <- sends(E)]], S1}
                  end, {[], S0}, lists:seq(1, 70)),
    ?assertEqual([{ack, #{received => 32}}, {ack, #{received => 64}}], Acks).

%% ---------------------------------------------------------------------------
%% Requests
%% ---------------------------------------------------------------------------

request_gets_its_feedback_once_test() ->
    S0 = up(8),
    {E1, S1} = ?S:request(r, signal(<<"q">>), 700, 1, S0),
    ?assertEqual([{timer, {request, <<"q">>}, 700}], [T || {timer, _, _} = T <- E1]),
    Fb = (delivered(1, 3))#{context => feedback, in_reply_to => <<"q">>},
    {ok, E2, S2} = ?S:incoming({ok, {signal, Fb}}, 1, S1),
    ?assertEqual([{r, {ok, Fb}}], replies(E2)),
    ?assertEqual([{cancel, {request, <<"q">>}}], [C || {cancel, _} = C <- E2]),
    Late = Fb#{seq => 2},
    {ok, E3, _} = ?S:incoming({ok, {signal, Late}}, 1, S2),
    ?assertEqual([{signal, Late}], notes(E3)).

request_times_out_also_while_blocked_test() ->
    S0 = up(1),
    {_, S1} = ?S:send(f, signal(<<"a">>), 1, S0),
    {E2, S2} = ?S:request(r, signal(<<"q">>), 700, 1, S1),
    ?assertEqual([], sends(E2)),
    {E3, S3} = ?S:request_timeout(<<"q">>, S2),
    ?assertEqual([{r, {error, timeout}}], replies(E3)),
    {ok, E4, _} = ?S:incoming({ok, {control, {ack, #{accepted => <<"a">>}}}}, 2, S3),
    ?assertEqual([], sends(E4)).

v1_request_and_finish_test() ->
    {connect, ?A, S0} = ?S:next_attempt(0, new(false)),
    {E0, S0} = ?S:request(r, signal(<<"q">>), 700, 1, S0),
    ?assertEqual([{r, {error, closed}}], replies(E0)),
    {ok, [], S1} = ?S:welcomed(maps:remove(ha, welcome(8)), 0, S0),
    {[{send, _, {request, <<"q">>}}, {timer, {request, <<"q">>}, 700}], S2} =
        ?S:request(r, signal(<<"q">>), 700, 1, S1),
    {[{reply, r, {error, closed}}], S3} = ?S:finish(S2),
    ?assertEqual({[], S3}, ?S:request_timeout(<<"q">>, S3)).

%% ---------------------------------------------------------------------------
%% Heartbeats and the resume
%% ---------------------------------------------------------------------------

silence_test() ->
    S0 = up(8),
    ?assertEqual({ok, [{timer, silence, 100}]}, ?S:silence_check(300, S0)),
    ?assertEqual({lost, server_silent}, ?S:silence_check(301, S0)),
    {ok, _, S1} = ?S:incoming({ok, {control, {ack, #{}}}}, 250, S0),
    ?assertEqual({ok, [{timer, silence, 100}]}, ?S:silence_check(550, S1)).

resume_sends_again_what_was_not_accepted_test() ->
    S0 = up(8),
    {_, S1} = ?S:send(f, signal(<<"a">>), 1, S0),
    {_, S2} = ?S:send(f, signal(<<"b">>), 1, S1),
    {ok, _, S3} = ?S:incoming({ok, {signal, delivered(1, 3)}}, 1, S2),
    {reconnect, [{cancel, silence}, {cancel, ack}], S4} = ?S:lost(closed, 5, S3),
    {connect, ?B, S5} = ?S:next_attempt(5, S4),
    ?assertEqual({control, {resume, #{pairing => <<"p">>, role => agent, entity_id => <<"va">>,
                                      credential => <<"c">>, protocol_version => 2,
                                      session_id => <<"SID">>, received => 1, epoch => 3}}},
                 parse(?S:hello(S5))),
    {ok, E6, _} = ?S:welcomed(welcome(8, true, <<"a">>), 6, S5),
    ?assertMatch([{signal, #{id := <<"b">>}}], [parse(F) || F <- sends(E6)]),
    ?assertMatch([{accepted, [<<"a">>]}, {reconnected, #{resumed := true, reason := closed}}],
                 notes(E6)).

new_session_describes_again_and_holds_signals_test() ->
    S5 = new_session_holding_a(),
    {ok, E6, S6} = ?S:incoming(binding([<<"va">>]), 7, S5),
    ?assertEqual([], sends(E6)),
    {ok, E7, _} = ?S:incoming(binding([<<"va">>, <<"av">>]), 8, S6),
    ?assertMatch([{signal, #{id := <<"a">>}}], [parse(F) || F <- sends(E7)]).

%% A described entity with signal "a" unacknowledged loses its connection
%% and gets a new session (Resumed false): it describes itself again at
%% once and holds "a".
new_session_holding_a() ->
    S0 = up(8),
    {_, S1} = ?S:describe(d, <<"DESC">>, S0),
    {_, S2} = ?S:send(f, signal(<<"a">>), 1, S1),
    {reconnect, _, S3} = ?S:lost(closed, 5, S2),
    {connect, _, S4} = ?S:next_attempt(5, S3),
    {ok, E5, S5} = ?S:welcomed(welcome(8), 6, S4),
    ?assertEqual([<<"DESC">>], sends(E5)),
    S5.

%% nemesis_SUITE (seed {50,657042514,491140}): after a power cut the
%% Avatar got a new session, was handed over to another node before the
%% VA was back and resumed there (Resumed true); the resume released the
%% held signals and 183 were refused UnknownReceiver. A resumed session
%% stays held until a Binding report names another entity.
resumed_new_session_stays_held_test() ->
    S5 = new_session_holding_a(),
    {reconnect, _, S6} = ?S:lost({refused, <<"NotActive">>, <<"handed over">>}, 7, S5),
    {connect, _, S7} = ?S:next_attempt(7, S6),
    {ok, E8, S8} = ?S:welcomed(welcome(8, true, <<>>), 8, S7),
    ?assertEqual([], sends(E8)),
    {E9, S9} = ?S:send(f, signal(<<"b">>), 9, S8),
    ?assertEqual([], sends(E9)),
    {ok, E10, S10} = ?S:incoming(binding([<<"va">>]), 10, S9),
    ?assertEqual([], sends(E10)),
    {ok, E11, S11} = ?S:incoming(binding([<<"va">>, <<"av">>]), 11, S10),
    ?assertMatch([{signal, #{id := <<"a">>}}, {signal, #{id := <<"b">>}}],
                 [parse(F) || F <- sends(E11)]),
    %% Released: what comes next goes at once.
    {E12, _} = ?S:send(f, signal(<<"c">>), 12, S11),
    ?assertMatch([{signal, #{id := <<"c">>}}], [parse(F) || F <- sends(E12)]).
