%% @doc Test support. Classifies every signal of a run the way Jepsen's
%% RabbitMQ checker classifies queue messages: for each direction (sender
%% to receiver) it compares what the sender sent, what the bridge told it
%% was accepted (`Ack'), and what the receiver got. Pure functions.
%% Part of the
%% cluster harness (evatar_test_cluster).
%%
%% | category | meaning |
%% |---|---|
%% | ok | accepted, and delivered exactly once |
%% | lost | accepted, never delivered |
%% | duplicated | delivered more than once |
%% | unexpected | delivered, never sent |
%% | recovered | sent, never acknowledged, delivered exactly once (allowed: the sender was not told) |
%% | unconfirmed | sent, never acknowledged, never delivered (allowed) |
%%
%% A run passes with zero lost, zero duplicated and zero unexpected.
%%
%% Across power cuts (every node killed at once), check_pairs/2 counts
%% apart the signals in flight at a cut that were lost or delivered twice:
%% they may be (docs/ha.md section 6); every other signal is held to the
%% same rules.
-module(evatar_test_checker).

-export([classify/3, check_pairs/1, check_pairs/2, merge/2, empty/0, passed/1, format/1]).

-export_type([result/0]).

-type result() :: #{ok := non_neg_integer(), lost := [binary()],
                    duplicated := [binary()], unexpected := [binary()],
                    recovered := non_neg_integer(), unconfirmed := non_neg_integer(),
                    lost_at_cut => non_neg_integer(), duplicated_at_cut => non_neg_integer()}.

-spec empty() -> result().
empty() ->
    #{ok => 0, lost => [], duplicated => [], unexpected => [], recovered => 0,
      unconfirmed => 0}.

%% @doc One direction: Sent (every SignalID the sender sent), Accepted (the
%% SignalIDs acknowledged to it), Delivered (the SignalIDs the receiver got,
%% one entry per delivery).
-spec classify([binary()], [binary()], [binary()]) -> result().
classify(Sent, Accepted, Delivered) ->
    SentSet = sets:from_list(Sent, [{version, 2}]),
    AccSet = sets:from_list(Accepted, [{version, 2}]),
    Counts = lists:foldl(fun(Id, M) -> maps:update_with(Id, fun(N) -> N + 1 end, 1, M) end,
                         #{}, Delivered),
    Times = fun(Id) -> maps:get(Id, Counts, 0) end,
    Unexpected = lists:sort([Id || Id <- maps:keys(Counts), not sets:is_element(Id, SentSet)]),
    Duplicated = lists:sort([Id || {Id, N} <- maps:to_list(Counts), N > 1,
                                   sets:is_element(Id, SentSet)]),
    Acc = sets:to_list(AccSet),
    NotAcked = [Id || Id <- sets:to_list(SentSet), not sets:is_element(Id, AccSet)],
    #{ok => length([Id || Id <- Acc, Times(Id) =:= 1]),
      lost => lists:sort([Id || Id <- Acc, Times(Id) =:= 0]),
      duplicated => Duplicated,
      unexpected => Unexpected,
      recovered => length([Id || Id <- NotAcked, Times(Id) =:= 1]),
      unconfirmed => length([Id || Id <- NotAcked, Times(Id) =:= 0])}.

%% @doc Both directions of each pair of evatar_test_traffic histories, summed.
-spec check_pairs([#{va := evatar_test_traffic:history(), av := evatar_test_traffic:history()}]) -> result().
check_pairs(Histories) ->
    lists:foldl(fun(#{va := Va, av := Av}, Acc) ->
                        merge(merge(direction(Va, Av), direction(Av, Va)), Acc)
                end, empty(), Histories).

direction(#{sent := Sent, accepted := Acc}, #{received := Rec}) ->
    classify(Sent, Acc, [Id || {Id, _Epoch} <- Rec]).

%% @doc As check_pairs/1, for a run with power cuts at `Cuts' (monotonic
%% ms of this node, each taken once every node was dead). A lost signal
%% acknowledged before a cut was in flight at that cut (only the two
%% instances' memory held it), and so was a lost feedback (SignalID "fb-"
%% and its request's) to a request delivered before a cut and answered
%% after it (the request, open at the cut, was forgotten: the feedback is
%% late); a signal delivered once before a cut and again after it was sent
%% again by a sender that had not had its Ack.
%% Those go to `lost_at_cut' and `duplicated_at_cut' (counts), not to
%% `lost' and `duplicated'.
-spec check_pairs([#{va := evatar_test_traffic:history(), av := evatar_test_traffic:history()}], [integer()]) ->
          result().
check_pairs(Histories, Cuts) ->
    lists:foldl(fun(#{va := Va, av := Av}, Acc) ->
                        merge(merge(cut(Va, Av, Cuts), cut(Av, Va, Cuts)), Acc)
                end, (empty())#{lost_at_cut => 0, duplicated_at_cut => 0}, Histories).

cut(#{accepted_at := AccAt, received_at := Asked} = From, #{received_at := RecAt} = To, Cuts) ->
    #{lost := Lost, duplicated := Dup} = R = direction(From, To),
    InFlight = fun(Id) ->
                       T = maps:get(Id, AccAt),
                       Open = case Id of
                                  <<"fb-", Req/binary>> -> maps:get(Req, Asked, []);
                                  _ -> []
                              end,
                       lists:any(fun(C) ->
                                         T < C orelse
                                             lists:any(fun(Q) -> Q < C andalso C < T end, Open)
                                 end, Cuts)
               end,
    Across = fun(Id) ->
                     Ts = maps:get(Id, RecAt),
                     lists:any(fun(C) -> lists:min(Ts) < C andalso C < lists:max(Ts) end, Cuts)
             end,
    {LostCut, LostAfter} = lists:partition(InFlight, Lost),
    {DupCut, DupAfter} = lists:partition(Across, Dup),
    R#{lost := LostAfter, duplicated := DupAfter, lost_at_cut => length(LostCut),
       duplicated_at_cut => length(DupCut)}.

-spec merge(result(), result()) -> result().
merge(A, B) ->
    maps:map(fun(K, V) when is_list(V) -> V ++ maps:get(K, B);
                (K, V) -> V + maps:get(K, B)
             end, A).

-spec passed(result()) -> boolean().
passed(#{lost := [], duplicated := [], unexpected := []}) -> true;
passed(_) -> false.

%% @doc One line of counts, then up to 10 SignalIDs of each failing category.
-spec format(result()) -> iolist().
format(#{ok := Ok, lost := L, duplicated := D, unexpected := U, recovered := R,
         unconfirmed := Un} = Result) ->
    [io_lib:format("ok ~b, lost ~b, duplicated ~b, unexpected ~b, recovered ~b, unconfirmed ~b",
                   [Ok, length(L), length(D), length(U), R, Un]),
     [io_lib:format(", in flight at the power cut: lost ~b, duplicated ~b", [LC, DC])
      || #{lost_at_cut := LC, duplicated_at_cut := DC} <- [Result]],
     [io_lib:format("~n  ~s: ~s", [Name, lists:join(" ", lists:sublist(Ids, 10))])
      || {Name, Ids} <- [{lost, L}, {duplicated, D}, {unexpected, U}], Ids =/= []]].
